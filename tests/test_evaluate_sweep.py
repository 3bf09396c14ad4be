"""evaluate --inputs 9,12,25: one run, the same held-out frames and margins for every N, results per N, a
verdict per reconstructor and N, and PSNR against N in the report; old single-N results still report."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sparself.core.errors import ConfigError
from sparself.evaluation import evaluate as ev
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.figures import grid_rows
from sparself.evaluation.report import write_report
from sparself.evaluation.results import NETWORK, FrameScore, ReconResult, ScoredSet, SeededSets
from sparself.evaluation.results_file import Results
from sparself.evaluation.scene_results import SceneResult
from sparself.evaluation.split import make_split
from sparself.evaluation.verdict import CANNOT_TELL, DOES_NOT_HELP, HELPS, decide, verdict
from test_evaluate import N_FRAMES, _capture, _hooks, _NearestRenderer, _tiny_cfg


def test_inputs_take_one_n_or_several_in_ascending_order():
    assert EvalConfig(inputs=25).inputs == (25,)
    assert EvalConfig(inputs=(25, 9, 12, 9)).inputs == (9, 12, 25)
    with pytest.raises(ConfigError, match="at least 3"):
        EvalConfig(inputs=(2, 9)).validate()


def test_every_n_holds_out_the_same_frames_within_the_same_margins():
    cfg = EvalConfig(inputs=(9, 12, 25))
    splits = {n: make_split(184, cfg, n) for n in cfg.inputs}  # llff_bird's frame count
    assert {len(s.inputs) for s in splits.values()} == {9, 12, 25}
    assert len({tuple(s.eval) for s in splits.values()}) == 1
    assert len({tuple(s.margin) for s in splits.values()}) == 1  # so the same frames are extrapolations
    assert len({tuple(s.group(i) for i in s.eval) for s in splits.values()}) == 1
    # the margin is the smallest N's input spacing: 183 / 10 frames
    assert splits[25].inputs[0] == 18 and splits[9].inputs[0] == 18
    # one N alone keeps its own rule
    assert make_split(184, EvalConfig(inputs=25)).inputs[0] == 9


def test_one_run_scores_every_n_on_the_same_frames_and_plots_psnr_against_n(tmp_path):
    hooks, calls = _hooks()
    hooks["reconstructors"] = {"nearest": _NearestRenderer}
    out = tmp_path / "out"
    res = ev.evaluate([_capture(tmp_path / "cap")], out, _tiny_cfg(inputs=(3, 5), seeds=1), **hooks)
    runs = res.ok
    assert [(s.status, s.name, s.capture, s.inputs_n) for s in runs] == [
        ("ok", "cap N=3", "cap", 3),
        ("ok", "cap N=5", "cap", 5),
    ]
    assert [len(s.split.inputs) for s in runs] == [3, 5]
    assert runs[0].split.scored == runs[1].split.scored
    assert [s.densification["nearest"].rows["base"].views for s in runs] == [3, 5]  # type: ignore[union-attr]
    assert calls == [0, 0]  # the network trained once per N
    assert json.loads((out / "results.json").read_text())["settings"]["inputs"] == [3, 5]
    md = (out / "report.md").read_text()
    verdict_part = md.split("## Protocol")[0]
    assert "- nearest at N = 3: " in verdict_part and "- nearest at N = 5: " in verdict_part
    assert "![cap PSNR against N](figures/sweep_cap.png)" in verdict_part
    assert (out / "figures" / "sweep_cap.png").stat().st_size > 1000
    # the tables list each N's run; no row averages runs of different N
    assert "| cap N=3" in md and "| cap N=5" in md and "| Average" not in md
    assert (out / "examples" / "cap_N_3").is_dir() and (out / "examples" / "cap_N_5").is_dir()


def test_a_sparse_capture_runs_once_whatever_n(tmp_path):
    hooks, calls = _hooks()
    hooks["reconstructors"] = {}
    cap = _capture(tmp_path / "cap")
    small = cap.subset(list(range(9)))  # 9 frames: too few for 5 inputs with real frames between them
    res = ev.run_evaluation([small], _tiny_cfg(inputs=(3, 5), seeds=1), None, **hooks)
    assert [(s.status, s.inputs_n) for s in res.scenes] == [("ok", 5)] and calls == [0]
    assert any(n.startswith("run once for N = 3, 5") for n in res.ok[0].notes)
    assert make_split(N_FRAMES, _tiny_cfg(inputs=(3, 5)), 3).kind == "dense"


def _scored(psnr: float, views: int, seed: int | None = None) -> ScoredSet:
    return ScoredSet([FrameScore("a.png", 1, psnr, 0.5, None)], seed=seed, views=views)


def _entry(base: float, net: float, std: float, oracle: float, instrument: str = "ok") -> ReconResult:
    """A reconstructor's rows: N at ``base`` dB, N + sparself at ``net`` ± ``std`` dB over two seeds, the oracle."""
    seeds = SeededSets([_scored(net - std, 35, 0), _scored(net + std, 35, 1)])
    rows = {"base": _scored(base, 25), NETWORK: seeds, "oracle": _scored(oracle, 35)}
    return ReconResult(rows, instrument=instrument, status="ok")


def test_verdict_weighs_the_gain_against_the_spread_over_seeds_and_the_instrument():
    assert decide(0.5, 0.2) == HELPS
    assert decide(0.3, 0.4) == CANNOT_TELL  # the spread covers the gain
    assert decide(-0.5, 0.2) == DOES_NOT_HELP and decide(0.05, None) == DOES_NOT_HELP
    assert decide(None, None) == CANNOT_TELL
    scenes = [
        SceneResult("a", densification={"3dgs": _entry(20.0, 21.0, 0.2, 22.0)}),
        SceneResult("b", densification={"3dgs": _entry(20.0, 19.0, 0.2, 19.5, "failed: ...")}),
    ]
    v = verdict(scenes, "3dgs", 25)
    assert v.word == HELPS and v.captures == 1 and v.failed == ["b"]
    assert v.change_db == pytest.approx(1.0) and v.share == pytest.approx(0.5) and v.spread_db == pytest.approx(0.2)
    s = v.sentence(sweep=False)
    assert s.startswith("3dgs: helps: N + sparself +1.00 dB PSNR over N ± 0.20 dB over seeds; 50 % of the oracle")
    assert "instrument failed on b" in s
    assert verdict(scenes[1:], "3dgs", 25).word == CANNOT_TELL


def test_verdict_names_the_seeds_that_end_below_n():
    base = SeededSets([_scored(20.0, 25, k) for k in range(3)])
    net = SeededSets([_scored(p, 35, k) for k, p in enumerate((21.0, 19.5, 19.95))])  # +1, -0.5, -0.05
    v = verdict([SceneResult("a", densification={"3dgs": ReconResult({"base": base, NETWORK: net})})], "3dgs", 25)
    assert (v.seeds, v.below) == (3, [pytest.approx(-0.5)])  # -0.05 is within MIN_CHANGE_DB of N
    assert "; below N on 1 of 3 capture seeds (worst -0.50 dB); 1 capture(s)." in v.sentence(sweep=False)
    fine = SeededSets([_scored(20.5, 35, k) for k in range(3)])
    even = verdict([SceneResult("a", densification={"3dgs": ReconResult({"base": base, NETWORK: fine})})], "3dgs", 25)
    assert even.below == [] and "below N" not in even.sentence(sweep=False)


def test_an_old_single_n_results_file_still_reports_without_a_sweep(tmp_path):
    scene = {
        "name": "toy",
        "status": "ok",
        "timings": {},
        "protocol": {"rule": "dense: ...", "held_out": ["a.png"], "scored": ["a.png"], "inputs": ["b.png"] * 25},
        "view_synthesis": {},
        "densification": {"mpi": _entry(20.0, 21.5, 0.1, 23.0).to_json()},
    }
    write_report(Results.from_json({"settings": {"inputs": 25, "seeds": 3}, "scenes": [scene]}), tmp_path)
    md = (tmp_path / "report.md").read_text()
    assert "- mpi: helps: N + sparself +1.50 dB PSNR over N ± 0.10 dB over seeds; 50 % of the oracle" in md
    assert "N = 25 evenly spaced" in md and not list((tmp_path / "figures").glob("sweep_*.png"))


def test_example_grid_wraps_into_a_row_per_reconstructor():
    labels = ["sparself", "blend", "flow"]
    labels += [f"{r} {v} views ({k})" for r in ("mpi", "3dgs") for v, k in ((25, "base"), (35, "sparself"))]
    labels += [f"3dgs 35 views (sparself seed {s})" for s in range(1, 7)]
    rows = grid_rows(labels, ["mpi", "3dgs"], columns=6)
    assert [(t, len(ls)) for t, ls in rows] == [("view synthesis", 3), ("mpi", 2), ("3dgs", 6), ("3dgs", 2)]
    assert np.all([ls == sorted(ls, key=labels.index) for _, ls in rows])


def test_batch_evaluate_refuses_a_sweep_rather_than_keep_one_n():
    from sparself.batch_units import evaluate_configs

    with pytest.raises(ConfigError, match="one N at a time"):
        evaluate_configs(EvalConfig(), {"inputs": [9, 25]})
    assert [c.inputs for _, c in evaluate_configs(EvalConfig(seeds=2), {"inputs": 9})] == [(9,), (9,)]


def test_the_oracle_share_says_how_many_captures_it_rests_on():
    no_oracle = _entry(20.0, 22.0, 0.1, 0.0)
    del no_oracle.rows["oracle"]
    scenes = [SceneResult("a", densification={"mpi": _entry(20.0, 21.0, 0.1, 22.0)})]
    scenes.append(SceneResult("ring", densification={"mpi": no_oracle}))
    v = verdict(scenes, "mpi", None)
    assert v.change_db == pytest.approx(1.5) and v.share == pytest.approx(0.5) and (v.captures, v.shared) == (2, 1)
    assert "50 % of the oracle's gain (+2.00 dB) on the 1 capture(s) with one; 2 capture(s)" in v.sentence(False)
