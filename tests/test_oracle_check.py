"""The instrument check: a reconstruction that more real photos make worse cannot measure densification."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from sparself.evaluation.report import write_report
from sparself.evaluation.results import NETWORK, FrameScore, ReconResult, ScoredSet, SeededSets
from sparself.evaluation.results_file import Results, Settings
from sparself.evaluation.scene_results import SceneResult


def _entry(base: float, net: float, oracle: float) -> ReconResult:
    s = lambda v, views, seed=None: ScoredSet([FrameScore("a.png", 1, v, 0.5, None)], seed, views)  # noqa: E731
    rows = {"base": s(base, 25), NETWORK: SeededSets([s(net, 35, 0)]), "oracle": s(oracle, 35)}
    return ReconResult(rows, status="ok")


def test_share_only_when_the_oracle_beats_n():
    ok = _entry(20.0, 21.0, 22.0)
    ok.check_instrument()
    assert ok.instrument == "ok" and ok.shares == {NETWORK: 0.5} and ok.oracle_gain_db == 2.0
    assert ok.to_json()["oracle_share"] == 0.5  # as results.json has always written it
    bad = _entry(23.42, 23.5, 22.73)  # a capture where more real photos scored lower
    bad.check_instrument()
    assert bad.instrument is not None and bad.instrument.startswith("failed") and "22.73" in bad.instrument
    assert bad.instrument_failed and bad.shares[NETWORK] is None
    no_oracle = _entry(20.0, 21.0, 0.0)
    del no_oracle.rows["oracle"]
    no_oracle.check_instrument()
    assert no_oracle.instrument is None and no_oracle.shares == {}
    assert "instrument" not in no_oracle.to_json() and "oracle_share" not in no_oracle.to_json()


def test_report_says_the_instrument_failed_instead_of_a_share(tmp_path):
    good, bad = _entry(20.0, 21.0, 22.0), _entry(23.42, 23.5, 22.73)
    for e in (good, bad):
        e.check_instrument()
    bad.fitted, bad.backend = True, "cpu: test"
    scenes: list = [SceneResult(n, status="ok", densification={"3dgs": e}) for n, e in (("good", good), ("bad", bad))]
    write_report(Results(Settings({"lpips_status": "unavailable"}), {}, scenes), tmp_path)
    md = (tmp_path / "report.md").read_text()
    good_rows = [line for line in md.splitlines() if line.startswith("| good (25→35)")]
    bad_rows = [line for line in md.splitlines() if line.startswith("| bad (25→35)")]
    assert any(line.rstrip().endswith("| 50% |") for line in good_rows)
    assert any("instrument failed (oracle -0.69 dB vs N)" in line for line in bad_rows)
    assert not any("%" in line for line in bad_rows)
    assert "3dgs ran on: cpu: test." in md


def test_oracle_benchmark_captures_are_nested_and_never_use_held_out_frames():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "oracle_check.py"
    spec = importlib.util.spec_from_file_location("oracle_check", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    held, caps = mod.nested_captures(184, [25, 35, 50, 90])
    assert held == list(range(8, 183, 8))
    assert [len(caps[n]) for n in (25, 35, 50, 90)] == [25, 35, 50, 90]
    assert set(caps[25]) <= set(caps[35]) <= set(caps[50]) <= set(caps[90])
    assert not set(caps[90]) & set(held)
