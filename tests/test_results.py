"""The typed results: results.json read back through ``from_json`` (the stored benchmark files included)
writes the same JSON again and renders a report; a file that is not results fails with one line."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import pytest

from sparself.core.errors import InputError
from sparself.evaluation.report import write_report
from sparself.evaluation.results import (
    NETWORK,
    NETWORK_WEIGHTED,
    FrameScore,
    ReconResult,
    RowError,
    ScoredSet,
    SeededSets,
    WeightChoice,
    paired_change,
)
from sparself.evaluation.results_file import Results, Settings, read_results
from sparself.evaluation.scene_results import PlannedPose, SceneFailure, SceneResult, SplitInfo, Timings

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


def _text(data: dict) -> str:
    return json.dumps(data, indent=1, allow_nan=True)


@pytest.mark.parametrize("name", ["3dgs_cpu", "gsplat_gpu"])
def test_stored_benchmark_results_load_write_back_unchanged_and_report(name, tmp_path):
    path = BENCH / f"{name}_results.json.gz"
    raw = json.loads(gzip.decompress(path.read_bytes()))
    res = read_results(path)
    assert _text(res.to_json()) == _text(raw)  # every key and number as the file has it
    s = res.ok[0]
    assert s.name == "llff_bird" and s.extra == {"wall_s": raw["scenes"][0]["wall_s"]}  # a benchmark's own key
    d = s.densification["3dgs"]
    assert (
        d.status == "ok" and d.instrument == "ok" and d.backend == raw["scenes"][0]["densification"]["3dgs"]["backend"]
    )
    assert d.shares[NETWORK] == raw["scenes"][0]["densification"]["3dgs"]["oracle_share"]
    base = d.rows["base"]
    assert isinstance(base, ScoredSet) and base.mean("psnr")[0] == pytest.approx(
        raw["scenes"][0]["densification"]["3dgs"]["base"]["summary"]["psnr"]["mean"]
    )
    md, _ = write_report(res, tmp_path)
    text = md.read_text()
    assert "## Verdict" in text and "- 3dgs: " in text and "| llff_bird (25→35) |" in text


def test_weighted_choice_and_failed_rows_round_trip():
    choice = WeightChoice(0.5, {"0.5": 21.0, "1.0": 20.5}, ["a", "b"], ["c", "d"], True, chosen_on_seed=0)
    frames = [
        FrameScore("f1", 1, 20.0, 0.5, None, "interpolated"),
        FrameScore("f9", 9, 18.0, 0.4, None, "extrapolated"),
    ]
    seeded = SeededSets([ScoredSet(frames, seed=s, views=8, decision=choice) for s in (0, 1)])
    partial = SeededSets([ScoredSet(frames, seed=0, views=8)], summarized=False)  # a fit failed after seed 0
    better = [FrameScore(f.frame, f.index, f.psnr + 2, f.ssim, None, f.group) for f in frames]
    ok = ReconResult({"base": ScoredSet(frames, views=5), NETWORK: seeded, "oracle": ScoredSet(better, views=8)})
    ok.rows[NETWORK_WEIGHTED] = RowError("RuntimeError: no fit")
    ok.fitted, ok.status, ok.seconds = True, "ok", 1.5
    ok.check_instrument()
    failed = ReconResult(
        {"base": ScoredSet(frames, views=5), NETWORK: partial}, status="failed", error="x", seconds=2.0
    )
    split = SplitInfo("dense", "rule", 10, planned=[PlannedPose("novel", 4.5, "interpolated", 4, "f4", 0.1, 2.0)])
    scene = SceneResult("cap N=5", "cap", 5, None, "ok", ["a note"], Timings(1.0, 2.0, 3.0), split=split)
    scene.densification = {"mpi": ok, "nerf": failed}
    res = Results(Settings({"inputs": [5]}), {"dietnerf": "not run"}, [scene, SceneFailure("b", "/b", "boom")])
    data = res.to_json()
    again = Results.from_json(json.loads(_text(data)))
    assert _text(again.to_json()) == _text(data)
    d = again.ok[0].densification
    assert isinstance(d["mpi"].rows[NETWORK_WEIGHTED], RowError) and d["mpi"].instrument == "ok"
    assert d["mpi"].oracle_gain_db == pytest.approx(2.0) and d["mpi"].shares == {NETWORK: 0.0}
    net = d["mpi"].rows[NETWORK]
    assert isinstance(net, SeededSets) and net.per_seed[1].decision == choice
    assert not d["nerf"].rows[NETWORK].has_summary and d["nerf"].rows[NETWORK].mean("psnr") == (None, None)
    assert "summary" not in data["scenes"][0]["densification"]["nerf"][NETWORK]  # as a failed fit always wrote it
    assert "backend" not in data["scenes"][0]["densification"]["nerf"] and again.failed[0].name == "b"


def test_an_evaluation_written_by_evaluate_reads_back_to_the_same_json(tmp_path):
    from sparself.evaluation import evaluate as ev
    from test_evaluate import _capture, _hooks, _NearestRenderer, _tiny_cfg

    hooks, _ = _hooks()
    hooks["reconstructors"] = {"nearest": _NearestRenderer}
    out = tmp_path / "out"
    res = ev.evaluate([_capture(tmp_path / "cap"), tmp_path / "missing"], out, _tiny_cfg(seeds=2), **hooks)
    written = (out / "results.json").read_text()
    assert _text(read_results(out / "results.json").to_json()) == written
    assert _text(res.to_json()) == written
    assert [s.status for s in res.scenes] == ["ok", "failed"]


@pytest.mark.parametrize(
    "content, why",
    [
        (b"not json", "JSONDecodeError"),
        (b'{"kind": "something else"}', '"scenes" list'),
        (b'{"scenes": [{"status": "ok"}]}', "KeyError"),
        (b'{"settings": {"kind": "densify"}, "scenes": []}', "batch densify"),
    ],
)
def test_a_file_that_is_not_results_fails_with_one_line_naming_it(tmp_path, content, why):
    path = tmp_path / "results.json"
    path.write_bytes(content)
    with pytest.raises(InputError) as e:
        read_results(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: not the results of a sparself evaluation") and why in msg and "\n" not in msg
    with pytest.raises(InputError, match="nothing.json"):
        read_results(tmp_path / "nothing.json")


def _seeded(psnrs: list[float]) -> SeededSets:
    return SeededSets([ScoredSet([FrameScore("a.png", 1, p, 0.5, None)], seed=k) for k, p in enumerate(psnrs)])


def test_a_change_over_n_is_taken_seed_against_seed_where_both_rows_have_the_seeds():
    # per seed +1 and 0 dB: mean 0.5, std 0.5; the rows' own spreads (1.0 and 1.5) do not enter
    assert paired_change(_seeded([21.0, 23.0]), _seeded([20.0, 23.0])) == pytest.approx((0.5, 0.5))
    # N fitted once: the difference of the means, with the row's spread over seeds
    once = ScoredSet([FrameScore("a.png", 1, 20.0, 0.5, None)])
    assert paired_change(_seeded([21.0, 23.0]), once) == pytest.approx((2.0, 1.0))
    assert paired_change(None, once) == (None, None)
