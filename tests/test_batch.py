"""sparself batch: many captures as Ray tasks (local Ray with 2 CPUs), resumable, isolated, interruptible,
with results equal to the single-process (--local) path."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from planescene import plane_scene
from sparself import batch, batch_ray
from sparself.core.errors import InputError, SparselfError
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.selfcheck import SelfCheckConfig
from sparself.pipeline import DensifyConfig
from sparself.synthesis.plan import PlanConfig
from sparself.synthesis.train_config import TrainConfig

TINY = DensifyConfig(
    train=TrainConfig(epochs=2, crop=32, planes=8, weights="none"),
    plan=PlanConfig(n_mid=2, n_extra=1),
    out_size=48,
    check=SelfCheckConfig(recon="none"),
)
# TINY on the command line: the same settings, so that a re-run through the API continues that batch
TINY_ARGS = [
    "--planes",
    "8",
    "--epochs",
    "2",
    "--crop",
    "32",
    "--n-mid",
    "2",
    "--n-extra",
    "1",
    "--out-size",
    "48",
    "--weights",
    "none",
    "--recon",
    "none",
]


def _write_capture(folder: Path, seed: int, n: int = 6) -> None:
    from sparself.capture import io as sio

    sc = plane_scene(xs=tuple(0.1 * i for i in range(n)), seed=seed)
    sc = replace(sc, frames=[replace(f, name=f"img{i}.png") for i, f in enumerate(sc.frames)])
    sio.write_scene(sc, folder)


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> Path:
    """Two tiny posed captures (textured plane, 6 views) and a broken one (NaN poses); manifests."""
    root = tmp_path_factory.mktemp("captures")
    _write_capture(root / "cap0", 0)
    _write_capture(root / "cap1", 1)
    (root / "broken").mkdir()
    np.save(root / "broken" / "poses_bounds.npy", np.full((4, 17), np.nan))
    (root / "three.txt").write_text("cap0\nbroken  # NaN poses\n\ncap1\n")
    (root / "two.txt").write_text("cap0\ncap1\n")
    return root


@pytest.fixture(scope="module")
def ray_local():
    """One local Ray with 2 CPUs for the module (start-up takes seconds); batch runs reuse it."""
    ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'sparself[ray]'); Ray tests skipped")
    tmp = tempfile.mkdtemp(prefix="sparself-ray-test-")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, _temp_dir=tmp)
    yield ray
    ray.shutdown()
    import shutil

    shutil.rmtree(tmp, ignore_errors=True)


def _leftovers(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".tmp-" in p.name]


def _files(folder: Path) -> dict[str, bytes]:
    """The densified scenes' bytes (the run folders hold wall-clock timings, so they are left out)."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and "/run/" not in str(p)
    }


def test_batch_densify_on_ray_isolates_failures_resumes_and_equals_local(captures, ray_local, tmp_path):
    out = tmp_path / "batch"
    res = batch.run_batch("densify", captures / "three.txt", out, TINY, batch.BatchConfig(progress=False))
    by = {u.capture: u for u in res.units}
    assert [u.capture for u in res.units] == ["cap0", "broken", "cap1"]
    assert by["cap0"].status == by["cap1"].status == "ok" and by["broken"].status == "failed"
    assert "poses_bounds.npy" in by["broken"].error and "NaN" in by["broken"].error
    assert "\n" not in by["broken"].error
    for name in ("cap0", "cap1"):  # each as `sparself densify` writes it: 6 views + 3 synthesized
        images = sorted(p.name for p in (out / "captures" / name / "scene" / "images").iterdir())
        assert len(images) == 9 and sum("novel_" in n for n in images) == 3
        assert (out / "captures" / name / "plan.json").is_file() and (out / "logs" / f"{name}.log").stat().st_size
        assert by[name].views == 6 and by[name].synthesized == 3
    assert not (out / "captures" / "broken").exists()
    assert "Traceback" in (out / "logs" / "broken.log").read_text()  # the full story is in the unit's log
    report = (out / "report.md").read_text()
    assert all(n in report for n in ("cap0", "cap1", "broken")) and "Captures that failed" in report
    data = json.loads((out / "results.json").read_text())
    assert [s["name"] for s in data["scenes"]] == ["cap0", "broken", "cap1"]
    assert data["failures"] == [{"capture": "broken", "seed": 0, "error": by["broken"].error}]
    assert (out / "report.html").is_file() and not _leftovers(out)

    # a re-run skips the two done (their files untouched) and tries the broken one again
    before = {p: p.stat().st_mtime_ns for p in (out / "captures").rglob("*") if p.is_file()}
    again = batch.run_batch("densify", captures / "three.txt", out, TINY, batch.BatchConfig(progress=False))
    assert [(u.capture, u.status, u.skipped) for u in again.units] == [
        ("cap0", "ok", True),
        ("broken", "failed", False),
        ("cap1", "ok", True),
    ]
    assert {p: p.stat().st_mtime_ns for p in before} == before
    assert "(earlier run)" in (out / "report.md").read_text()

    # the same manifest in one process without Ray: byte-identical scenes
    local = tmp_path / "local"
    res_l = batch.run_batch(
        "densify", captures / "three.txt", local, TINY, batch.BatchConfig(local=True, progress=False)
    )
    assert [(u.capture, u.status, u.error) for u in res_l.units] == [(u.capture, u.status, u.error) for u in res.units]
    assert _files(local / "captures") == _files(out / "captures") and len(_files(out / "captures")) > 20


def test_batch_evaluate_merges_seeds_and_equals_local(captures, ray_local, tmp_path):
    man = captures / "eval.json"
    man.write_text(
        json.dumps(
            {
                "defaults": {
                    "size": 32,
                    "inputs": 5,
                    "n_mid": 2,
                    "n_extra": 1,
                    "epochs": 1,
                    "reconstructors": ["mpi"],
                    "baselines": ["blend"],
                    "densify_baselines": ["blend"],
                    "lpips": False,
                    "max_eval": 2,
                    "seeds": 1,
                },
                "captures": [{"path": "cap0", "seeds": 2}, {"path": "broken", "name": "bad"}],
            }
        )
    )
    base = EvalConfig(progress=False)
    runs = {}
    for mode, cfg in (
        ("ray", batch.BatchConfig(progress=False)),
        ("local", batch.BatchConfig(local=True, progress=False)),
    ):
        res = batch.run_batch("evaluate", man, tmp_path / mode, base, cfg)
        assert [(u.capture, u.seed, u.status) for u in res.units] == [
            ("cap0", 0, "ok"),
            ("cap0", 1, "ok"),
            ("bad", 0, "failed"),
        ]
        runs[mode] = json.loads((tmp_path / mode / "results.json").read_text())
        assert (tmp_path / mode / "captures" / "cap0" / "seed1" / "report.md").is_file()
        assert not _leftovers(tmp_path / mode)
    ray_scene, local_scene = runs["ray"]["scenes"][0], runs["local"]["scenes"][0]
    per_seed = ray_scene["view_synthesis"]["sparself"]["per_seed"]
    assert [s["seed"] for s in per_seed] == [0, 1]
    psnr = [s["summary"]["psnr"]["mean"] for s in per_seed]
    summary = ray_scene["view_synthesis"]["sparself"]["summary"]["psnr"]
    assert summary["n_seeds"] == 2 and summary["mean"] == pytest.approx(np.mean(psnr))
    assert summary["std"] == pytest.approx(np.std(psnr)) and psnr[0] != psnr[1]  # seeds differ, merged
    assert [s["seed"] for s in ray_scene["densification"]["mpi"]["sparself"]["per_seed"]] == [0, 1]
    # each seed unit chose its synthetic-frame weight on its own views; both weighted fits are merged
    assert [s["seed"] for s in ray_scene["densification"]["mpi"]["sparself_weighted"]["per_seed"]] == [0, 1]
    assert "blend" in ray_scene["view_synthesis"]  # the seed-0 unit carried the baselines
    assert ray_scene["view_synthesis"] == local_scene["view_synthesis"]  # same numbers with and without Ray
    assert (
        ray_scene["densification"]["mpi"]["sparself"]["per_seed"]
        == local_scene["densification"]["mpi"]["sparself"]["per_seed"]
    )
    assert runs["ray"]["scenes"][1]["status"] == "failed" and "seed 0:" in runs["ray"]["scenes"][1]["error"]
    md = (tmp_path / "ray" / "report.md").read_text()
    assert "mean ± std over 1 capture(s)" in md and "| bad | 0 | failed |" in md


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "sparself.cli", "batch", *args]


def test_sigterm_cancels_the_batch_and_a_rerun_completes_it(captures, ray_local, tmp_path):
    out = tmp_path / "killed"
    args = ["densify", str(captures / "two.txt"), "--out", str(out), "--workers", "1", "-q", *TINY_ARGS]
    args[args.index("--epochs") + 1] = "6"  # long enough to be killed while training
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(_cli(*args), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while not (out / "logs" / "cap0.log").exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143 and "interrupted by SIGTERM" in err, err
    assert "interrupted" in err and "Traceback" not in err
    assert not _leftovers(out), _leftovers(out)
    assert not (out / "captures" / "cap1").exists()  # one unit at a time: the second never started
    assert not (out / "results.json").exists()
    # the re-run (here on the test's Ray) finishes the batch; nothing is left behind
    res = batch.run_batch(
        "densify",
        captures / "two.txt",
        out,
        replace(TINY, train=replace(TINY.train, epochs=6)),
        batch.BatchConfig(progress=False),
    )
    assert [u.status for u in res.units] == ["ok", "ok"]
    assert not _leftovers(out) and (out / "report.md").is_file()


# ---- without Ray ------------------------------------------------------------------------------------


def test_manifest_formats_and_errors(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    js = tmp_path / "m.json"
    js.write_text(
        json.dumps(
            {"defaults": {"epochs": 3}, "captures": ["a", {"path": "b", "name": "bee", "n_mid": 4, "holdout": [1, 2]}]}
        )
    )
    caps = batch.read_manifest(js, "densify")
    assert [(c.name, c.path, c.options) for c in caps] == [
        ("a", tmp_path / "a", {"epochs": 3}),
        ("bee", tmp_path / "b", {"epochs": 3, "n_mid": 4, "holdout": (1, 2)}),
    ]
    units = batch.make_units("densify", caps, TINY, tmp_path / "out")
    assert units[1].config.plan.n_mid == 4 and units[1].config.train.epochs == 3 and units[0].config.plan.n_mid == 2
    assert units[1].out == tmp_path / "out" / "captures" / "bee"
    js.write_text(json.dumps(["a", {"path": "b", "epochz": 3}]))
    with pytest.raises(InputError, match=r"m\.json: capture 2: unknown option\(s\) epochz"):
        batch.read_manifest(js, "densify")
    (tmp_path / "dup.txt").write_text("a\na\n")
    with pytest.raises(InputError, match="two captures are named 'a'"):
        batch.read_manifest(tmp_path / "dup.txt", "densify")
    js.write_text(json.dumps([{"path": "a", "name": ".."}]))  # would be OUT/captures/.., i.e. OUT itself
    with pytest.raises(InputError, match=r"m\.json: capture name '\.\.' contains '\.\.'"):
        batch.read_manifest(js, "densify")
    js.write_text(json.dumps([{"path": "a", "name": "Cap"}, {"path": "b", "name": "cap"}]))  # one folder on macOS
    with pytest.raises(InputError, match="differ only in case"):
        batch.read_manifest(js, "densify")
    (tmp_path / "one.txt").write_text("a\n")
    ev_units = batch.make_units(
        "evaluate", batch.read_manifest(tmp_path / "one.txt", "evaluate"), EvalConfig(seeds=3), tmp_path / "out"
    )
    assert [(u.seed, u.config.first_seed, u.config.seeds, u.config.oracle) for u in ev_units] == [
        (0, 0, 1, True),
        (1, 1, 1, False),
        (2, 2, 1, False),
    ]
    pytest.importorskip("yaml")
    ym = tmp_path / "m.yaml"
    ym.write_text("captures:\n  - path: a\n    seeds: 2\n")
    assert batch.read_manifest(ym, "evaluate")[0].options == {"seeds": 2}


def test_missing_ray_says_how_to_install(tmp_path, monkeypatch, capsys):
    from sparself.cli import main

    (tmp_path / "m.txt").write_text("cap\n")
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(SparselfError, match=r"pip install 'sparself\[ray\]'"):
        with batch_ray.ray_session(batch.BatchConfig(), tmp_path):
            pass
    assert main(["batch", "densify", str(tmp_path / "m.txt"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sparself[ray]" in err[0] and "--local" in err[0]


def test_batch_refuses_a_folder_it_does_not_own(tmp_path, capsys):
    from sparself.cli import main

    (tmp_path / "m.txt").write_text("cap\n")
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "precious.txt").write_text("keep")
    assert main(["batch", "densify", str(tmp_path / "m.txt"), "--out", str(tmp_path / "o"), "--local"]) == 2
    assert "not a sparself batch folder" in capsys.readouterr().err
    assert (tmp_path / "o" / "precious.txt").read_text() == "keep" and len(list((tmp_path / "o").iterdir())) == 1
