"""Interrupted and repeated runs: a killed training run resumes to the same weights, the same
command with the same seed gives byte-identical images, an interrupted command leaves nothing behind,
and inputs are never modified. All on CPU, through the CLI, on a 6-view 32x24 scene."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sparself.cli import main
from test_bad_input import listing, make_scene, need, write_posed

# one thread everywhere: the in-process and subprocess runs must reduce in the same order to agree bit for bit
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
TRAIN = ["--size", "32", "--crop", "16", "--device", "cpu", "--backbone-size", "32", "--seed", "3"]
DENSIFY = [*TRAIN[2:], "--check-steps", "30"]  # densify trains at the scene's size; short self-check fits


def cli(*argv) -> list[str]:
    return [sys.executable, "-m", "sparself.cli", *[str(a) for a in argv]]


def snapshot(folder: Path) -> dict:
    """Content hash and modification time of every file and folder under ``folder``."""
    out = {}
    for p in sorted([folder, *folder.rglob("*")]):
        st = p.stat()
        out[str(p.relative_to(folder))] = (
            hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir",
            st.st_mtime_ns,
        )
    return out


def read_only(folder: Path, on: bool = True) -> None:
    for p in [folder, *folder.rglob("*")]:
        os.chmod(p, (0o555 if p.is_dir() else 0o444) if on else (0o755 if p.is_dir() else 0o644))


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    """A posed 6-view scene, read-only for the whole module; its snapshot is checked at the end."""
    folder = write_posed(tmp_path_factory.mktemp("input") / "scene", make_scene(6), "llff")
    before = snapshot(folder)
    read_only(folder)
    yield folder
    read_only(folder, on=False)
    assert snapshot(folder) == before, "an input file or folder was modified"


def _weights(path: Path) -> dict:
    import torch

    ck = torch.load(path, map_location="cpu", weights_only=False)
    return {"epoch": ck["epoch"], "model": ck["model"]}


def test_killed_training_resumes_to_the_same_weights(scene, tmp_path):
    """Train 9 epochs (checkpoints at 5 and 9) uninterrupted, and again killed with SIGKILL right after
    the epoch-5 checkpoint appears; ``--resume`` then finishes with bit-identical weights and log."""
    need("train")
    import torch

    full, part = tmp_path / "full", tmp_path / "part"
    uninterrupted = subprocess.Popen(
        cli("train", scene, "--out", full, "--epochs", "9", *TRAIN, "-q"),
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    killed = subprocess.Popen(
        cli("train", scene, "--out", part, "--epochs", "9", *TRAIN, "-q"),
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    t0 = time.monotonic()
    while not (part / "checkpoint.pt").exists() and killed.poll() is None and time.monotonic() - t0 < 60:
        time.sleep(0.002)
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    assert _weights(part / "checkpoint.pt")["epoch"] == 5, "the kill came too late to test anything"
    assert killed.returncode == -signal.SIGKILL
    _, err = uninterrupted.communicate(timeout=120)
    assert uninterrupted.returncode == 0, err.decode()
    resumed = subprocess.run(
        cli("train", scene, "--out", part, "--epochs", "9", *TRAIN, "--resume", "-q"),
        env=ENV,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert resumed.returncode == 0, resumed.stderr
    a, b = _weights(full / "checkpoint.pt"), _weights(part / "checkpoint.pt")
    assert a["epoch"] == b["epoch"] == 9
    assert a["model"].keys() == b["model"].keys()
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k

    # the log of the resumed run has each epoch once, with the uninterrupted run's losses
    def losses(p):
        return [ln.split(",")[:2] for ln in (p / "train_log.csv").read_text().splitlines()]

    assert losses(part) == losses(full) and len(losses(full)) == 10

    # killed before the first checkpoint (what a kill in epochs 1-5 leaves: config and a partial log):
    # --resume starts again and ends the same
    early = tmp_path / "early"
    early.mkdir()
    for name in ("config.json", ".sparself-output"):
        (early / name).write_bytes((full / name).read_bytes())
    (early / "train_log.csv").write_text("\n".join((full / "train_log.csv").read_text().splitlines()[:3]) + "\n")
    again = subprocess.run(
        cli("train", scene, "--out", early, "--epochs", "9", *TRAIN, "--resume", "-q"),
        env=ENV,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert again.returncode == 0 and "no checkpoint yet" in again.stderr, again.stderr
    c = _weights(early / "checkpoint.pt")
    assert c["epoch"] == 9 and all(torch.equal(a["model"][k], c["model"][k]) for k in a["model"])
    assert losses(early) == losses(full)


def test_same_seed_twice_gives_byte_identical_images(scene, tmp_path, capsys):
    """``sparself densify`` twice with the same seed: every written image and pose file is identical."""
    need("densify")
    import torch

    torch.set_num_threads(1)
    outs = []
    for k in range(2):
        out = tmp_path / f"dense{k}"
        code = main(
            [
                str(a)
                for a in (
                    "densify",
                    scene,
                    "--out",
                    out,
                    "--epochs",
                    "1",
                    "--n-mid",
                    "2",
                    "--n-extra",
                    "1",
                    *DENSIFY,
                    "--recon",  # every planned view is written, so every synthesized image is compared
                    "none",
                    "-q",
                )
            ]
        )
        assert code == 0, capsys.readouterr().err
        outs.append(out)
    files = sorted(str(p.relative_to(outs[0])) for p in outs[0].rglob("*") if p.is_file())
    assert files == sorted(str(p.relative_to(outs[1])) for p in outs[1].rglob("*") if p.is_file())
    novel = [f for f in files if f.startswith("scene/images/") and "novel_" in f]
    assert len(novel) == 3
    for f in files:
        if f.endswith((".png", ".jpg", ".npy", ".bin", ".json")) and not f.endswith("config.json"):
            assert (outs[0] / f).read_bytes() == (outs[1] / f).read_bytes(), f
    a, b = _weights(outs[0] / "run" / "checkpoint.pt"), _weights(outs[1] / "run" / "checkpoint.pt")
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])


def test_interrupted_command_leaves_nothing(scene, tmp_path):
    """Ctrl-C (SIGINT) in the middle of ``densify``: 'interrupted', exit 130, no output and no temporary
    folder left beside it; the same command then runs normally."""
    need("densify")
    res = tmp_path / "res"
    res.mkdir()
    argv = cli("densify", scene, "--out", res / "out", "--epochs", "200", "--n-mid", "2", "--n-extra", "1", *DENSIFY)
    proc = subprocess.Popen(
        [*argv, "--checkpoint-every", "1000"], env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    t0 = time.monotonic()
    # wait until training writes into its work folder (a hidden .out.sparself-work beside the output), before its
    # first checkpoint: nothing finished, so nothing is kept
    work_log = ".out.sparself-work/runs/*/train_log.csv"
    while proc.poll() is None and time.monotonic() - t0 < 300 and not list(res.glob(work_log)):
        time.sleep(0.01)
    assert proc.poll() is None, proc.communicate()[1]
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "sparself densify: interrupted" in err and "Traceback" not in err, err
    assert listing(res) == []


def test_leftovers_of_a_killed_run_are_removed_by_the_next_one(tmp_path):
    """SIGKILL runs no cleanup, so its hidden temporary folder stays; the next run writing the same output
    removes it (its process is dead) but keeps the temporary folder of a process that is still alive (here a
    scratch folder: a second writer of the output itself is refused by its lock)."""
    from sparself.core.outputs import atomic_dir

    out = tmp_path / "out"
    code = (
        "import sys, time\nfrom pathlib import Path\nfrom sparself.core.outputs import atomic_dir\n"
        "with atomic_dir(Path(sys.argv[1])) as t:\n"
        "    (t / 'part.txt').write_text('half')\n    print('ready', flush=True)\n    time.sleep(60)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code, str(out)], env=ENV, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    scratch = code.replace("atomic_dir", "scratch_dir").replace("[1]))", "[1]), 'sfm')")
    live = subprocess.Popen([sys.executable, "-c", scratch, str(out)], env=ENV, stdout=subprocess.PIPE, text=True)
    assert live.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    dead_tmp = [p for p in tmp_path.glob(".out.tmp-*") if p.name.startswith(f".out.tmp-{proc.pid}-")]
    assert len(dead_tmp) == 1 and (dead_tmp[0] / "part.txt").exists()
    try:
        with atomic_dir(out) as t:
            (t / "result.txt").write_text("done")
        assert not dead_tmp[0].exists()
        assert [p.name.split("-")[1] for p in tmp_path.glob(".out.tmp-*")] == [str(live.pid)]
        assert (out / "result.txt").read_text() == "done"
    finally:
        live.kill()
        live.wait()
