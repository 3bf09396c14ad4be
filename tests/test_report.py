"""The report: paper-shaped tables, LPIPS never printed as a number without weights, failures listed."""

from __future__ import annotations

import re

import numpy as np

from sparself.evaluation.conclusions import conclusions
from sparself.evaluation.document import fmt
from sparself.evaluation.report import write_report
from sparself.evaluation.results import FrameScore, ReconResult, ScoredSet, SeededSets
from sparself.evaluation.results_file import Results, Settings
from sparself.evaluation.scene_results import SceneFailure, SceneResult, SplitInfo, Timings, ViewSynthesisResult


def _scored(psnr, ssim, lpips, views=None, seed=None) -> ScoredSet:
    return ScoredSet([FrameScore("a.png", 1, psnr, ssim, lpips)], seed=seed, views=views)


def _seeded(psnr, ssim, lpips, views=None) -> SeededSets:
    """Two seeds 0.1 below and above each value: mean ± 0.1 over seeds."""
    return SeededSets(
        [
            _scored(psnr + d, ssim + d, None if lpips is None else lpips + d, views, seed)
            for seed, d in enumerate((-0.1, 0.1))
        ]
    )


def _results(lpips_status: str, lp_value) -> Results:
    mpi = ReconResult(
        {
            "base": _scored(20.0, 0.6, lp_value, views=25),
            "sparself": _seeded(21.5, 0.65, lp_value, views=35),
            "oracle": _scored(23.0, 0.7, lp_value, views=35),
        },
        status="ok",
    )
    mpi.check_instrument()
    scene = SceneResult(
        "toy",
        status="ok",
        timings=Timings(1.0, 2.0, 3.0),
        split=SplitInfo(kind="dense", rule="dense: ...", held_out=["a.png"], scored=["a.png"], inputs=["b.png"]),
        synthesis=ViewSynthesisResult(
            {"sparself": _seeded(24.0, 0.8, lp_value), "blend": _scored(23.0, 0.7, lp_value)}
        ),
        densification={"mpi": mpi},
    )
    return Results(
        Settings({"inputs": 25, "seeds": 3, "lpips_status": lpips_status, "versions": {"torch": "x"}}),
        {"dietnerf": "not run: needs CLIP weights that cannot be fetched here"},
        [scene, SceneFailure("broken", None, "InputError: x.png: not an image")],
    )


def _lpips_rows(md: str) -> list[str]:
    """Table rows under every LPIPS heading/caption."""
    rows, on = [], False
    for line in md.splitlines():
        if "LPIPS ↓" in line:
            on = True
        elif line.startswith("#") or (line and not line.startswith("|") and on):
            on = "LPIPS ↓" in line
        elif on and line.startswith("| ") and not line.startswith("| Scene"):
            rows.append(line)
    return rows


def test_lpips_is_never_a_number_when_unavailable(tmp_path):
    # even if a value slipped into the results, no weights means no number
    write_report(_results("unavailable: weights not found", 0.25), tmp_path)
    md = (tmp_path / "report.md").read_text()
    # no LPIPS table at all; why is said once, in the "Not run" list
    assert _lpips_rows(md) == [] and "LPIPS ↓" not in md
    lines = md.splitlines()
    assert sum("unavailable: weights not found" in ln for ln in lines if not ln.startswith("| lpips_status")) == 1
    assert "- LPIPS: unavailable: weights not found" in lines
    assert "0.250" not in md
    html = (tmp_path / "report.html").read_text()
    assert "0.250" not in html and "unavailable" in html
    assert html.count("<table>") == sum(ln.startswith("|---") for ln in lines)  # the same tables as report.md
    assert html.count("<table>") == 10  # PSNR and SSIM x 3, the failed scene, settings, packages, timings
    assert not (tmp_path / "figures" / "densification_lpips.png").exists()


def test_lpips_numbers_printed_when_available_and_tables_shaped_like_the_paper(tmp_path):
    write_report(_results("available: LPIPS v0.1 AlexNet (a, b)", 0.25), tmp_path)
    md = (tmp_path / "report.md").read_text()
    assert "| Scene | mpi N | mpi N+synth | mpi change |" in md
    assert re.search(r"\| toy \| 20\.00 \| 21\.50 ± 0\.10 \| \+1\.50 \|", md)
    assert "| Average | 20.00 | 21.50 | +1.50 |" in md
    assert "| toy | 0.250 | 0.250 ± 0.100 | +0.000 |" in md
    assert "| toy (25→35) | 20.00 | 21.50 ± 0.10 | 23.00 | 50% |" in md
    assert "dietnerf: not run: needs CLIP weights" in md
    assert "Scenes that failed" in md and "x.png: not an image" in md
    assert (tmp_path / "figures" / "densification_psnr.png").stat().st_size > 1000
    assert (tmp_path / "report.html").read_text().count("<table>") >= 6


def test_fmt_and_conclusions():
    assert fmt("psnr", 21.456) == "21.46" and fmt("ssim", 0.5, 0.01) == "0.500 ± 0.010"
    assert fmt("lpips", None) == "unavailable" and fmt("lpips", 0.2, lpips_ok=False) == "unavailable"
    assert fmt("psnr", float("nan")) == "–" and fmt("psnr", np.inf) == "–"
    text = " ".join(conclusions(_results("unavailable", None)))
    assert "mpi: N + sparself views beats N views on average by PSNR (+1.50 dB" in text
    assert "sparself (24.00 dB) beats the best baseline, blend (23.00 dB)" in text


def test_notes_on_frames_at_the_views_poses_stand_under_the_verdict(tmp_path):
    from sparself.evaluation.results import AT_VIEWS

    results = _results("unavailable: weights not found", None)
    toy = results.scenes[0]
    assert isinstance(toy, SceneResult)
    toy.notes = [AT_VIEWS + "1 of 1 scored held-out frames lie at a planned view's pose", "40 points triangulated"]
    write_report(results, tmp_path)
    md = (tmp_path / "report.md").read_text()
    verdict, rest = md.split("## Protocol", 1)
    assert "- toy: 1 of 1 scored held-out frames lie at a planned view's pose" in verdict.splitlines()
    assert "planned view's pose" not in rest  # said once, beside the verdict it qualifies
    assert "- toy: 40 points triangulated" in rest.split("## Not run", 1)[1].splitlines()
