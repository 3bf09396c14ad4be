"""The CPU 3DGS's reach past the sparse points, chosen per capture on held-back input views: the choice reads
only the inputs, fits without the views it scores, picks the best score (the first on ties), skips captures
where the reach changes nothing, and is recorded, read back and reported."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from planescene import DEPTH, camera_line, plane_image, render_plane
from sparself.evaluation import reach
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.densification import reach_chosen
from sparself.evaluation.results import ReachChoice, ReconResult
from sparself.recon.pool import Fitter

OFFSET = {1.0: 0.1, 5.0: 0.02}  # each reach's fake fit renders the plane off by this much: PSNR 20 and 33.98 dB


class _Off:
    """A fit that renders the true plane shifted by a constant: PSNR = -20 log10(offset), by hand."""

    def __init__(self, offset: float):
        self.offset = offset

    def render(self, pose, camera):
        return render_plane(pose, camera, DEPTH, 0, None) + self.offset


def _scene(bounds=None):
    sc = camera_line(np.linspace(0, 0.8, 9), (32, 24), 26.0, plane_image(), bounds=bounds)
    rng = np.random.default_rng(0)
    sc.points = np.stack([rng.uniform(-0.5, 0.5, 200), rng.uniform(-0.3, 0.3, 200), np.full(200, DEPTH)], 1)
    return sc


@pytest.fixture
def fits(monkeypatch):
    seen: list = []

    def fit_all(fitters, scenes, pool=None):
        seen.extend(zip(fitters, scenes))
        return [_Off(OFFSET.get(f.settings["far_reach"], 0.1)) for f in fitters]

    monkeypatch.setattr(reach, "fit_all", fit_all)
    return seen


def test_the_reach_whose_fit_renders_the_held_back_inputs_best_is_chosen_from_fits_without_them(fits):
    sc = _scene()
    got = reach.choose_reach(sc, Fitter("splat", {"seed": 0}), (1.0, 5.0), seed=7)
    assert isinstance(got, ReachChoice) and got.reach == 5.0 and got.chosen_on_seed == 7
    assert got.validation_views == ["src2", "src7"]  # every 5th interior input from the third
    assert got.validation_psnr == pytest.approx({"1.0": 20.0, "5.0": -20 * np.log10(0.02)})
    assert [f.settings for f, _ in fits] == [{"seed": 7, "far_reach": 1.0}, {"seed": 7, "far_reach": 5.0}]
    for _, train in fits:  # the fits never see the views they are scored on
        assert [f.name for f in train.frames] == [f"src{i}" for i in (0, 1, 3, 4, 5, 6, 8)]


def test_equal_scores_keep_the_first_reach(fits):
    got = reach.choose_reach(_scene(), Fitter("splat", {"seed": 0}), (3.0, 2.0), seed=0)  # both fits alike
    assert got is not None and got.reach == 3.0 and len(set(got.validation_psnr.values())) == 1


def test_nothing_is_fitted_where_the_reach_changes_nothing(fits):
    """Depth bounds from the capture's files, or too few inputs to hold one back: the reach is left alone."""
    assert reach.choose_reach(_scene(bounds=(1.0, 10.0)), Fitter("splat", {}), (1.0, 5.0), seed=0) is None
    two = _scene()
    two.frames = two.frames[:2]
    assert reach.choose_reach(two, Fitter("splat", {}), (1.0, 5.0), seed=0) is None
    assert fits == []


def test_the_protocols_rows_fit_with_the_chosen_reach_and_record_it(fits):
    ev = SimpleNamespace(cfg=EvalConfig(splat_far_reach=(1.0, 5.0), recon_seed=3, first_seed=2), inputs=_scene())
    ev.name = "plane"
    entry = ReconResult()
    fit = Fitter("splat", {"seed": 3, "far_reach": 1.0})
    chosen = reach_chosen(ev, fit, entry, pool=None)
    assert isinstance(chosen, Fitter) and chosen.settings == {"seed": 3, "far_reach": 5.0}
    assert entry.reach is not None and entry.reach.chosen_on_seed == 3  # seed 0's, as in every batch unit
    one = SimpleNamespace(cfg=EvalConfig(splat_far_reach=(5.0,)), inputs=_scene(), name="plane")
    assert reach_chosen(one, fit, ReconResult(), pool=None) is fit  # one reach: nothing to choose


def test_the_choice_is_read_back_beside_the_rows_and_reported(tmp_path):
    from sparself.evaluation.report import _reach_choices

    choice = ReachChoice(5.0, {"1.0": 14.25, "5.0": 15.5}, ["a", "b"], 0)
    back = ReconResult.from_json(ReconResult(reach=choice).to_json())
    assert back.reach == choice and back.rows == {}
    lines: list[str] = []
    doc = SimpleNamespace(p=lines.append, ul=lines.extend)
    ctx = SimpleNamespace(ok=[SimpleNamespace(name="cap", densification={"3dgs": back})])
    _reach_choices(doc, ctx, "3dgs")
    assert "cap: 5x (fits with seed 0 without the inputs a, b, scored on those: 1x: 14.25 dB, 5x: 15.50 dB)" in lines


def test_the_self_checks_fits_start_as_far_as_the_rows_fits():
    from sparself.core.errors import ConfigError
    from sparself.evaluation.checked import check_config
    from sparself.evaluation.selfcheck import SelfCheckConfig, check_settings
    from sparself.recon import backend

    if backend("3dgs") != "splat":
        pytest.skip("3dgs runs on gsplat here, which keeps its own recipe")
    assert check_settings(SelfCheckConfig(recon="3dgs", far_reach=(5.0,)))["far_reach"] == 5.0
    assert "far_reach" not in check_settings(SelfCheckConfig(recon="3dgs", far_reach=(1.0,)))  # the fits' own default
    assert SelfCheckConfig().far_reach == EvalConfig().splat_far_reach == (1.0, 5.0)  # densify and its row alike
    assert "far_reach" not in check_settings(SelfCheckConfig(recon="nerf", far_reach=(5.0,)))
    ev = SimpleNamespace(cfg=EvalConfig(), net_synths=[object()])
    got = check_config(ev, "3dgs", 0, 5.0)
    assert got is not None and got.far_reach == (5.0,)  # the rows' reach, not chosen again
    for bad in [(0.5,), ()]:
        with pytest.raises(ConfigError, match="far_reach must be one or more reaches >= 1"):
            SelfCheckConfig(far_reach=bad).validate()


def test_densify_chooses_its_checks_reach_on_held_back_inputs_and_records_it(fits):
    from sparself.capture.io.dense import SelfCheck
    from sparself.evaluation.selfcheck import Checked, SelfCheckConfig, _reach_chosen, _with_reach
    from sparself.recon import backend

    if backend("3dgs") != "splat":
        pytest.skip("3dgs runs on gsplat here, which keeps its own recipe")
    cfg = SelfCheckConfig(recon="3dgs", far_reach=(1.0, 5.0), check_seed=4, check_size=24)
    got, choice = _reach_chosen(_scene(), cfg, pool=None)
    assert got.far_reach == (5.0,) and choice is not None and choice.reach == 5.0 and choice.chosen_on_seed == 4
    assert [f.settings["far_reach"] for f, _ in fits] == [1.0, 5.0]
    assert {f.settings["steps"] for f, _ in fits} == {cfg.check_steps}  # the check's own fits
    assert {sc.cameras[1].width for _, sc in fits} == {24}  # at the check's size
    assert _reach_chosen(_scene(), SelfCheckConfig(recon="3dgs", far_reach=(5.0,)), pool=None) == (
        SelfCheckConfig(recon="3dgs", far_reach=(5.0,)),
        None,
    )
    record = SelfCheck("3dgs", "weak", ("src2",), 20.0, ((1.0, 20.0),), None, None, (), "no view kept")
    checked = _with_reach(Checked([], np.zeros((0, 2, 2, 3)), None, record), choice)
    assert checked.record is not None and checked.record.far_reach == 5.0
    assert checked.record.reason.startswith("no view kept; random starting points to 5x the sparse points' far depth")
    assert SelfCheck.from_json(checked.record.to_json()) == checked.record
