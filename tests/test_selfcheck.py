"""densify's self-check: views are planned where the reconstruction is weak and written only when they raise
its PSNR on held-back input photos, so a densified capture is never worse than its photos alone."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, replace

import numpy as np
import pytest

from planescene import plane_scene, render_plane, small_plane_scene
from sparself import pipeline
from sparself.capture.io import read_scene, write_scene
from sparself.capture.io.dense import Confirmation, FillControl, GapTrend, SelfCheck, ViewCheck, read_selfcheck
from sparself.core.content import same_content
from sparself.core.geometry import Pose
from sparself.evaluation.folds import (
    beyond,
    check_folds,
    checkable,
    confirm_folds,
    measuring_fold,
    measuring_photos,
    one_wide_gain,
    stand_ins,
    trend_fold,
    view_gains,
    widened_gaps,
)
from sparself.evaluation.selfcheck import SelfCheckConfig, informative_confidence, weakest_plan, weights_of
from sparself.synthesis.plan import PlanConfig, candidate_poses, pick_poses, plan_poses, weakness_decides
from sparself.synthesis.synthesize import Synthesized

PLAN = PlanConfig(n_mid=4, n_extra=2)
# the geometry these tests spell out is that of views judged outside their own gaps; the control against
# content-free fills (three more fits a fold) is off except where a test protects it. The fits run at the
# check's default size (64 px, two thirds of the views' side), as densify's do.
MPI = SelfCheckConfig(recon="mpi", plan_mode="paper", check_size=64, gain_gap="other", fill_control=False)
MPI_FILLS = replace(MPI, fill_control=None)  # the MPI's default: on


def _line(n: int = 12):
    return plane_scene(xs=tuple(0.1 * i for i in range(n)))  # 96 x 64 views of a textured plane


def _densify(tmp_path, monkeypatch, views, check=MPI, resume=False):
    """densify with the network replaced by ``views(scene, targets) -> images`` (no training)."""

    def fake_train(scene, path, cfg):
        path.mkdir(parents=True)
        return None

    def fake_synth(run, scene, targets):
        imgs = views(scene, targets)
        return Synthesized(imgs, np.full(imgs.shape[:3], 0.9, np.float32))

    def fake_resumable(parent, scene, cfg, **_):
        (parent / "run").mkdir(parents=True, exist_ok=True)
        return argparse.Namespace(path=parent / "run")

    monkeypatch.setattr(pipeline, "train", fake_train)
    monkeypatch.setattr(pipeline, "train_resumable", fake_resumable)
    monkeypatch.setattr(pipeline, "synthesize_with_confidence", fake_synth)
    cfg = pipeline.DensifyConfig(plan=PLAN, check=check, triangulate=False, keep_run=False, downscaled=False)
    return pipeline.densify(_line(), tmp_path / "out", cfg, resume=resume)


def _exact(scene, targets):
    return np.stack([render_plane(t.pose, scene.cameras[t.camera_id]) for t in targets])


def _noise(scene, targets):
    cam = scene.cameras[targets[0].camera_id]
    return np.random.default_rng(0).random((len(targets), cam.height, cam.width, 3)).astype(np.float32)


def test_bad_views_are_not_written_and_sparself_json_says_why(tmp_path, monkeypatch, caplog):
    dense = _densify(tmp_path, monkeypatch, _noise, check=MPI_FILLS)
    folder = tmp_path / "out" / "scene"
    assert not any(f.synthetic for f in dense.frames) and len(read_scene(folder)) == 12
    rec = read_selfcheck(folder)
    assert rec.kept == () and rec.weight is None and len(rec.views) == 6
    assert "without synthesized views" in rec.reason and "mpi" in rec.reason
    assert max(p for _, p in rec.psnr_by_weight) < rec.psnr_without  # noise made every fit worse
    # noise loses between the inputs; past them it can gain by covering the end photos, and the fill
    # control drops every view that gains so
    gaining = {v.name for v in rec.views if v.gain is not None and v.gain > 0}
    assert gaining <= {v.name for v in rec.views if not 0 <= v.index <= 11}
    assert gaining <= set(rec.fill_control.dropped if rec.fill_control else ())
    assert [r.getMessage() for r in caplog.records if "self-check" in r.getMessage()] == [f"self-check: {rec.reason}"]


def _misplaced(scene, targets):
    """Views of the plane seen from the wrong place: a camera half the capture aside (a network that copies
    a far photo), so each disagrees with the photos around its pose."""

    def aside(t):
        return Pose.from_center(t.pose.qvec, t.pose.center + np.array([0.6, 0.25, 0.0]))

    return np.stack([render_plane(aside(t), scene.cameras[t.camera_id]) for t in targets])


def test_views_past_the_ends_that_only_cover_the_end_photos_are_not_written(tmp_path, monkeypatch):
    """Past the inputs the MPI leaves part of a held-back end photo uncovered (black), and any view there gains
    by covering it: misplaced views gain over the fit without them, but no more than content-free fills at the
    same poses (flat or noise), so the fill control drops them, and the record says so."""
    # fitted at the views' full size (96 px), where the uncovered strip of each end photo is what decides
    dense = _densify(tmp_path, monkeypatch, _misplaced, check=replace(MPI_FILLS, check_size=96))
    rec = read_selfcheck(tmp_path / "out" / "scene")
    past = [v for v in rec.views if not 0 <= v.index <= 11]
    assert len(past) == 2 and all(v.gain > 0 for v in past)  # they gain at the end photos: coverage
    assert not any(f.synthetic for f in dense.frames) and rec.kept == ()
    c = rec.fill_control
    assert c is not None and set(c.dropped) == {v.name for v in past} and len(c.photos) == 2
    assert len(c.psnr_noise) == 2
    # at each photo some fill renders it at least as well as the views
    assert all(v <= max(f, *n) for v, f, n in zip(c.psnr_views, c.psnr_flat, c.psnr_noise))
    assert "flat and two noise fills" in rec.reason


def test_good_views_are_kept_with_their_gains_on_the_paper_plan(tmp_path, monkeypatch):
    dense = _densify(tmp_path, monkeypatch, _exact)
    folder = tmp_path / "out" / "scene"
    rec = read_selfcheck(folder)
    planned = plan_poses(_line(), PLAN)  # --plan paper: exactly today's plan
    assert [v.name for v in rec.views] == [f.name for f in planned]
    # exact views far from a held-back photo may not raise the MPI there: a view is kept where it gains
    assert [f.name for f in dense.frames if f.synthetic] == list(rec.kept)
    assert rec.kept and {v.name for v in rec.views if v.gain > 0} <= set(rec.kept)
    assert rec.weight in weights_of(MPI) and rec.psnr_kept > rec.psnr_without
    doc = json.loads((folder / "sparself.json").read_text())
    test = {f["source_name"] for f in doc["frames"] if f["name"] in doc["split"]["test"]}
    inputs = [f.name for f in _line().frames if f.name not in test]  # the test photos never reach the check
    # three folds: every 5th interior input from the third, then from the fifth, then both ends; each planned
    # view is measured by the first fold that does not hold back one of its neighbouring photos (views past
    # the ends: by the ends fold)
    assert test and rec.validation == (inputs[2], inputs[7], inputs[4], inputs[0], inputs[-1])
    checked = _line().subset([i for i, f in enumerate(_line().frames) if f.name in inputs])
    assert (measuring_fold(checked, planned, "other") >= 0).all() and all(v.gain is not None for v in rec.views)
    # the fixer was tried on those same photos; exact views cannot be beaten, so it was not used
    assert rec.fixer is not None and rec.fixer.held_back == rec.validation and not rec.fixer.used
    written = json.loads((tmp_path / "out" / "plan.json").read_text())["frames"]
    for f, w in zip(planned, written):
        np.testing.assert_allclose(w["qvec"], f.pose.qvec) and np.testing.assert_allclose(w["tvec"], f.pose.tvec)
    back = read_scene(folder)
    syn = [i for i, f in enumerate(back.frames) if f.synthetic]
    # exact views agree with the MPI's render over most pixels: their exported confidence is lowered there
    masks = [back.confidence_map(i) for i in syn]
    assert all(m.max() <= 0.9 * rec.weight + 1 / 255 for m in masks)
    assert min(float(np.mean(m < 0.9 * rec.weight - 0.05)) for m in masks) > 0.1


def test_a_later_round_of_render_fix_refit_is_recorded_and_when_not_kept_changes_nothing_written(tmp_path, monkeypatch):
    one = _densify(tmp_path / "one", monkeypatch, _exact)
    two = _densify(tmp_path / "two", monkeypatch, _exact, check=replace(MPI, fix_rounds=2))
    rec = read_selfcheck(tmp_path / "two" / "out" / "scene")
    # exact views: no fixer beats them, in the first round or in the second, with the fits with them rendered
    [round_] = rec.rounds
    assert round_.psnr_after is None and not round_.kept and not round_.fixer.used
    assert round_.fixer.held_back == rec.validation and round_.fixer.psnr_render > rec.psnr_without
    assert (
        "round 2's fixer did not beat both" in rec.reason
        and rec.kept == read_selfcheck(tmp_path / "one" / "out" / "scene").kept
    )
    for a, b in zip(one.frames, two.frames):
        assert a.name == b.name and (
            not a.synthetic or np.array_equal(one.load(one.frames.index(a)), two.load(two.frames.index(b)))
        )


def test_confirmed_views_are_written_and_unconfirmed_ones_are_not(tmp_path, monkeypatch):
    from sparself.evaluation import selfcheck

    check = replace(MPI, confirm=True)
    dense = _densify(tmp_path / "a", monkeypatch, _exact, check)
    rec = read_selfcheck(tmp_path / "a" / "out" / "scene")
    c = rec.confirmation
    assert c is not None and c.confirmed and len(c.gains) == len(c.photos) > 1  # exact views lose nowhere
    assert not set(c.photos) & set(rec.validation)  # tested on photos no fold held back
    assert rec.kept and [f.name for f in dense.frames if f.synthetic] == list(rec.kept) and "confirmed" in rec.reason
    first = rec.kept
    failed = Confirmation(c.photos, (0.5,) + (-1.5,) * (len(c.photos) - 1), False)
    monkeypatch.setattr(selfcheck, "_confirmation", lambda *a: (failed, a[3]))
    dense = _densify(tmp_path / "b", monkeypatch, _exact, check)
    rec = read_selfcheck(tmp_path / "b" / "out" / "scene")
    assert not any(f.synthetic for f in dense.frames) and rec.kept == () and rec.psnr_kept is None
    assert rec.confirmation == failed and "not confirmed" in rec.reason and "without synthesized views" in rec.reason

    # views the confirmation drops before confirming the rest are neither written nor recorded as kept
    def pruned(inputs, small, planned, keep, *rest):
        left = keep.copy()
        left[np.flatnonzero(keep)[0]] = False
        gone = planned[int(np.flatnonzero(keep)[0])].name
        return Confirmation(c.photos, c.gains, True, (gone,), failed.gains), left

    monkeypatch.setattr(selfcheck, "_confirmation", pruned)
    dense = _densify(tmp_path / "c", monkeypatch, _exact, check)
    rec = read_selfcheck(tmp_path / "c" / "out" / "scene")
    written = [f.name for f in dense.frames if f.synthetic]
    assert written == list(rec.kept) == [n for n in first if n != rec.confirmation.dropped[0]]


def test_recon_none_writes_every_view_of_the_paper_plan_without_any_fit(tmp_path, monkeypatch):
    """The CLI end to end with --recon none: no reconstructor runs, the plan is the paper's, every view and
    its network confidence is written as before the self-check existed, and sparself.json has no record."""
    from sparself import cli, recon
    from sparself.capture.io.dense import mask_values
    from sparself.synthesis.synthesize import synthesize_with_confidence

    monkeypatch.setattr(recon, "get_reconstructor", lambda name: pytest.fail(f"fitted {name}"))
    write_scene(small_plane_scene(), tmp_path / "cap")  # 7 views, 40 x 28
    net = ["--epochs", "1", "--crop", "16", "--planes", "8", "--channels", "4", "--fc-side", "12"]
    args = [
        "densify",
        str(tmp_path / "cap"),
        "--out",
        str(tmp_path / "out"),
        "--recon",
        "none",
        "-q",
        "--no-downscaled",
    ]
    assert (
        cli.main(
            [
                *args,
                *net,
                "--backbone-size",
                "32",
                "--weights",
                "none",
                "--n-mid",
                "3",
                "--n-extra",
                "2",
                "--device",
                "cpu",
            ]
        )
        == 0
    )
    folder = tmp_path / "out" / "scene"
    assert "selfcheck" not in json.loads((folder / "sparself.json").read_text()) and read_selfcheck(folder) is None
    back = read_scene(folder)
    planned = plan_poses(read_scene(tmp_path / "cap"), PlanConfig(n_mid=3, n_extra=2))
    syn = [i for i, f in enumerate(back.frames) if f.synthetic]
    assert len(syn) == 5 and len(back) == 12
    for i, f in zip(syn, planned):
        np.testing.assert_allclose(back.frames[i].pose.w2c(), f.pose.w2c(), atol=1e-6)
    cap = read_scene(tmp_path / "cap")  # the views are made from the photos outside the written test split
    made = synthesize_with_confidence(
        tmp_path / "out" / "run", cap.without(pipeline.test_positions(cap, planned)), planned
    )
    for k, i in enumerate(syn):  # the network's confidence, not lowered
        np.testing.assert_array_equal(np.round(back.confidence_map(i) * 255), mask_values(made.confidence[k]))


def test_agreeing_pixels_get_lower_confidence():
    cfg = SelfCheckConfig(agree_within=0.05, agree_weight=0.25)
    ref = np.full((2, 9, 9, 3), 0.5, np.float32)
    img = ref.copy()
    img[1] += 0.2  # differs by 0.2 > 2 x 0.05 everywhere: informative
    img[0, :, :, 0] += 0.225  # mean over channels 0.075: halfway between 0.05 and 0.1
    out = informative_confidence(img, np.full((2, 9, 9), 0.8, np.float32), ref, cfg)
    np.testing.assert_allclose(out[1], 0.8, atol=1e-6)
    np.testing.assert_allclose(out[0], 0.8 * (0.25 + 0.75 * 0.5), atol=1e-5)
    assert np.array_equal(informative_confidence(ref, None, ref, cfg), np.full((2, 9, 9), 0.25, np.float32))


def test_uniform_pixel_weights_fit_and_write_every_pixel_of_a_view_alike():
    from sparself.evaluation import selfcheck

    scene, cfg = _line(12), replace(MPI, pixel_weights="uniform")
    planned = plan_poses(scene, PLAN)
    fitted: list = []
    check = selfcheck.check_fits(cfg)

    def fits(scenes):
        fitted.extend(f for sc in scenes for f in sc.frames if f.synthetic)
        return check(scenes)

    def synth(sc, targets):
        return Synthesized(_exact(sc, targets), np.full((len(targets), 64, 96), 0.4, np.float32))

    checked = selfcheck.self_check(scene, planned, synth, synth(scene, planned), cfg, "paper", fits)
    # the network's confidence (0.4) reaches neither the check's fits nor the written masks: only the weight
    assert fitted and all(f.confidence is None and f.weight in weights_of(cfg) for f in fitted)
    assert checked.frames and checked.confidence is not None
    assert np.array_equal(checked.confidence, np.full(checked.confidence.shape, checked.record.weight, np.float32))


def test_chosen_pixel_weights_fit_the_views_both_ways_and_use_the_better_on_the_held_back_photos(monkeypatch):
    """Uniformly weighted views are judged beside context views weighted alike too, against a fit without
    views made again beside those (as the final fit weighs every view one way)."""
    from sparself.evaluation import selfcheck
    from sparself.evaluation.weighting import ValidationViews

    views = ValidationViews(np.zeros((1, 2, 2, 3), np.float32), np.ones((1, 2, 2), np.float32), [])
    context = selfcheck._Context([], views, 1.0)
    fold = selfcheck._Fold([1, 5], "base", [0], [1], [], views, None, None, context)  # type: ignore[arg-type]
    monkeypatch.setattr(selfcheck, "informative_confidence", lambda img, conf, ref, cfg: np.ones(img.shape[:3]))
    # a scene stands for itself: how its views are weighted, and its context's weighting when it is the inputs'
    monkeypatch.setattr(
        selfcheck,
        "weight_scenes",
        lambda small, frames, v, weights, held: [
            ("uniform" if v.confidence is None else "confidence", w) for w in weights
        ],
    )
    monkeypatch.setattr(selfcheck, "validation_split", lambda small, held: (None, "inputs"))
    monkeypatch.setattr(
        selfcheck,
        "_with_context",
        lambda sc, c: sc if isinstance(sc, tuple) else f"{sc} {'alike' if c.views.confidence is None else 'confident'}",
    )
    cfg = SelfCheckConfig(pixel_weights="choose", check_weights=(0.5, 1.0))

    def settle(psnr, c=cfg):
        monkeypatch.setattr(
            selfcheck, "held_back_psnr", lambda small, r, held: np.asarray(psnr[r])[[[1, 5].index(h) for h in held]]
        )
        fitted: list = []
        ranked, tried = selfcheck._pixel_weighted(None, [fold], lambda scenes: fitted.extend(scenes) or scenes, None, c)
        own, scored, chosen = ranked[0]
        assert {r[2].pixel_weights for r in ranked} == ({"confidence", "uniform"} if tried else {chosen.pixel_weights})
        return (own, scored, tried, chosen), fitted

    psnr = {
        "base": [20.0, 20.0],
        "inputs alike": [19.0, 19.0],
        ("confidence", 0.5): [21.0, 0.0],
        ("confidence", 1.0): [20.5, 0.0],
        ("uniform", 0.5): [20.0, 0.0],
        ("uniform", 1.0): [21.5, 0.0],
    }
    ([own], [(scores, lowered)], tried, chosen), fitted = settle(psnr)
    # every fit of both ways in one call; each way judged at its best weight, at the scored photo only
    assert sorted(map(str, fitted)) == sorted(str(k) for k in psnr if k != "base")
    assert tried == (("confidence", 21.0), ("uniform", 21.5)) and chosen.pixel_weights == "uniform"
    assert lowered.confidence is None and scores.by_weight == {0.5: [20.0], 1.0: [21.5]}
    assert own.base == "inputs alike" and own.context.views.confidence is None and scores.without == [19.0]
    psnr[("uniform", 1.0)] = [21.0, 0.0]  # a tie keeps the network's confidence and the fold as it was
    ([own], [(scores, lowered)], tried, chosen), _ = settle(psnr)
    assert chosen.pixel_weights == "confidence" and lowered.confidence is not None and scores.by_weight[0.5] == [21.0]
    assert own is fold and scores.without == [20.0]
    # asked for one way, the check fits only that one and records no choice
    (_, _, tried, chosen), fitted = settle(psnr, replace(cfg, pixel_weights="confidence"))
    assert tried == () and chosen.pixel_weights == "confidence" and {k for k, _ in fitted} == {"confidence"}


def test_chosen_pixel_weights_fall_back_to_the_other_way_when_the_better_keeps_no_view(monkeypatch):
    from sparself.evaluation import selfcheck

    scene, cfg = _line(12), replace(MPI, pixel_weights="choose", confirm=True)
    planned = plan_poses(scene, PLAN)
    weighted = selfcheck._pixel_weighted

    def uniform_first(*args):
        ranked, tried = weighted(*args)
        return sorted(ranked, key=lambda r: r[2].pixel_weights != "uniform"), tried

    def confirmation(inputs, small, planned, keep, w, synth, fits, fix, c):
        gains = (-0.5, -2.0) if c.pixel_weights == "uniform" else (0.5, 0.25)
        return (Confirmation(("a", "b"), gains, c.pixel_weights != "uniform") if keep.any() else None), keep

    monkeypatch.setattr(selfcheck, "_pixel_weighted", uniform_first)
    monkeypatch.setattr(selfcheck, "_confirmation", confirmation)

    def synth(sc, targets):
        return Synthesized(_exact(sc, targets), np.full((len(targets), 64, 96), 0.4, np.float32))

    checked = selfcheck.self_check(scene, planned, synth, synth(scene, planned), cfg, "paper")
    rec = checked.record
    # the views are written as the confirmed way fitted them: the network's confidence, not the weight alone
    assert checked.frames and rec.pixel_weights == "confidence" and rec.confirmation.confirmed
    assert checked.confidence.max() <= 0.4 + 1e-6 and {m for m, _ in rec.psnr_by_pixel_weights} == {
        "confidence",
        "uniform",
    }
    assert "not confirmed (-1.25 dB on the mean (standard error 0.75), worst -2.00)" in rec.reason
    # when neither way keeps a view, the record is the first way's
    monkeypatch.setattr(selfcheck, "_confirmation", lambda *a: (Confirmation(("a",), (-0.5,), False), a[3]))
    none = selfcheck.self_check(scene, planned, synth, synth(scene, planned), cfg, "paper")
    assert not none.frames and none.record.pixel_weights == "uniform" and not none.record.confirmation.confirmed


def test_a_views_gain_is_the_gain_at_its_nearest_held_back_inputs():
    scene = _line(12)  # held back: positions 2 and 7
    frames = [replace(scene.frames[0], name=f"v{k}", index=x) for k, x in enumerate((1.5, 4.5, 6.0, 9.5))]
    # 4.5 is equally far from 2 and 7: the mean of both
    np.testing.assert_allclose(view_gains(scene, frames, np.array([1.0, -3.0])), [1.0, -1.0, -3.0, -3.0])


def test_a_fold_is_scored_only_at_the_held_back_photos_nearest_its_views():
    """Views past the first input, judged by the fold holding both ends back, are scored at the first
    photo only: the last one measures none of them (its change there is not theirs to answer for)."""
    scene = _line(12)
    start = [replace(scene.frames[0], name=f"v{k}", index=x) for k, x in enumerate((-0.8, -0.4))]
    assert measuring_photos(scene, start, [0, 11]) == [0]
    # a view equally far from two held-back photos is measured by both; one beside 7 by 7 alone
    both = [replace(scene.frames[0], name="mid", index=4.5), replace(scene.frames[0], name="near", index=8.0)]
    assert measuring_photos(scene, both, [2, 7]) == [2, 7]
    assert measuring_photos(scene, both[1:], [2, 7]) == [7]


class _Bump:
    """A fake fit that renders a bump centred at x = ``at`` (width ``width``) when ``on``, zeros otherwise."""

    def __init__(self, on: bool, at: float, width: float):
        self.on, self.at, self.width = on, at, width

    def render(self, pose: Pose, cam):
        v = np.exp(-(((pose.center[0] - self.at) / self.width) ** 2)) if self.on else 0.0
        return np.full((cam.height, cam.width, 3), v, np.float32)


def _halves_disagree_at(at: float, width: float):
    """fits(scenes) where the half starting at the second input renders a bump, the other zeros."""
    return lambda scenes: [_Bump(sc.frames[0].name == "src1", at, width) for sc in scenes]


def test_the_weak_plan_takes_the_gap_and_the_end_where_the_halves_disagree():
    scene = _line(8)
    picked = weakest_plan(scene, PlanConfig(n_mid=2, n_extra=1), _halves_disagree_at(0.42, 0.05), "other")
    # the gaps that disagree most on average, 4-5 (the bump at x = 0.42 is a fifth of the way in) and 3-4,
    # each at its midpoint, where a fit on both of its inputs is farthest from either; then the end
    assert [f.index for f in picked] == [3.5, 4.5, 7.2]
    cands = candidate_poses(scene, PlanConfig(n_mid=2, n_extra=1))
    assert len(cands) == 7 * 3 + 2 * 2 and sum(c.beyond for c in cands) == 4
    assert {c.frame.index for c in cands if c.beyond} == {-0.2, -0.4, 7.2, 7.4}
    weak = np.array([1.0 if c.slot == 0 else 0.0 for c in cands])  # all of gap 0 weak: one view there only
    assert [f.index for f in pick_poses(cands, weak, PlanConfig(n_mid=2, n_extra=0))] == [0.5, 1.5]
    # extrapolations alternate between the ends, the weaker first, further out at the second visit
    start = np.array([1.0 if c.slot == -1 else 0.0 for c in cands])
    assert [f.index for f in pick_poses(cands, start, PlanConfig(n_mid=0, n_extra=1))] == [-0.2]
    assert [f.index for f in pick_poses(cands, start, PlanConfig(n_mid=0, n_extra=3))] == [-0.4, -0.2, 7.2]


def test_views_between_the_neighbours_of_a_held_back_input_are_not_checkable():
    scene = _line(12)  # held back: positions 2 and 7, so the gaps 1..3 and 6..8 are twice as wide in the check
    xs = (-0.2, 0.5, 1.0, 1.5, 2.5, 3.0, 4.5, 6.5, 7.5, 8.0, 11.2)
    frames = [replace(scene.frames[0], name=f"v{k}", index=x) for k, x in enumerate(xs)]
    assert checkable(scene, frames, "other").tolist() == [
        False,
        True,
        True,
        False,
        False,
        True,
        True,
        False,
        False,
        True,
        False,
    ]
    assert checkable(scene, frames, "other", [0, 11]).tolist() == [True] + [False] * 9 + [
        True
    ]  # the ends fold: past the ends only


def test_two_folds_of_held_back_inputs_measure_every_gap_between_them():
    assert check_folds(25, "other") == [[2, 7, 12, 17, 22], [4, 9, 14, 19], [0, 24]]
    assert check_folds(9, "other") == [[2, 7], [4], [0, 8]]
    assert check_folds(5, "other") == [[2]]  # too few inputs for a second fold or for the ends fold
    scene = _line(12)  # folds [2, 7] and [4, 9]: widened gaps 1..3, 6..8 and 3..5, 8..10; the ends [0, 11]
    xs = (0.5, 1.5, 2.5, 3.5, 4.5, 6.5, 8.5, 9.5, 10.5, 11.2, -0.4)
    frames = [replace(scene.frames[0], name=f"v{k}", index=x) for k, x in enumerate(xs)]
    assert measuring_fold(scene, frames, "other").tolist() == [0, 1, 1, 0, 0, 1, 0, 0, 0, 2, 2]
    assert measuring_fold(_line(5), frames[:3] + frames[-2:], "other").tolist() == [0, -1, -1, -1, -1]


def test_measured_in_its_own_gap_a_view_is_judged_by_the_fold_that_widens_it():
    scene = _line(12)  # own folds [1, 5, 9] and [3, 7, 10]: every gap has one input held back; the ends [0, 11]
    assert check_folds(12, "own") == [[1, 5, 9], [3, 7, 10], [0, 11]]
    xs = (0.5, 1.5, 2.5, 3.5, 4.5, 6.5, 8.5, 9.5, 10.5, 11.2, -0.4)
    frames = [replace(scene.frames[0], name=f"v{k}", index=x) for k, x in enumerate(xs)]
    assert measuring_fold(scene, frames, "own").tolist() == [0, 0, 1, 1, 0, 1, 0, 0, 1, 2, 2]
    interior = frames[:9]
    own, other = checkable(scene, interior, "own", [2, 7]), checkable(scene, interior, "other", [2, 7])
    assert (own == ~other).all() and own.tolist() == [False, True, True, False, False, True, False, False, False]


@pytest.mark.parametrize("n", [3, 4, 5, 6, 9, 10, 12, 25, 26])
def test_own_gap_folds_hold_back_one_input_of_every_gap_and_never_two_neighbours(n):
    folds = check_folds(n, "own")
    interior = [f for f in folds if f != [0, n - 1]]
    assert len(interior) <= 2 and all(0 < p < n - 1 for f in interior for p in f)
    assert all(abs(a - b) > 1 for f in interior for a in f for b in f if a != b)
    assert all({g, g + 1} & set(sum(interior, [])) for g in range(n - 1))  # every gap g (inputs g, g + 1)
    scene = _line(n)
    mids = [replace(scene.frames[0], name=f"m{g}", index=g + 0.5) for g in range(n - 1)]
    assert (measuring_fold(scene, mids, "own") >= 0).all()


@pytest.mark.parametrize("gap", ["own", "other"])
@pytest.mark.parametrize("n", [3, 4, 5, 9, 10, 12, 25, 26])
def test_the_confirmation_holds_back_every_interior_photo_the_folds_leave_and_never_two_neighbours(n, gap):
    held = confirm_folds(n, gap)
    used = {p for f in check_folds(n, gap) for p in f}
    assert sorted(sum(held, [])) == [p for p in range(1, n - 1) if p not in used]
    assert len(held) <= 2 and all(abs(a - b) > 1 for f in held for a in f for b in f if a != b)


def _confirming(monkeypatch, psnr_with, cfg: SelfCheckConfig, kept=(0, 2)):
    """The kept views' confirmation on a 12-input line, every fit without views at 20 dB at every photo and
    each with views at ``psnr_with(photo position, the names of its synthetic frames)``: (the confirmation,
    the views it leaves kept, the photos each synthesis saw, the scene)."""
    from sparself.evaluation import selfcheck

    scene = _line(12)
    small = selfcheck.at_check_size(scene, cfg)
    planned = plan_poses(scene, PLAN)
    seen: list[set[str]] = []

    def synth(sc, targets):
        seen.append({f.name for f in sc.frames})
        cam = sc.cameras[targets[0].camera_id]
        return np.zeros((len(targets), cam.height, cam.width, 3), np.float32)

    def fits(scenes):
        return [frozenset(f.name for f in sc.frames if f.synthetic) for sc in scenes]

    def psnr(small, fit, held):
        return np.array([psnr_with(p, fit) if fit else 20.0 for p in held])

    monkeypatch.setattr(selfcheck, "renders", lambda r, sc, frames: np.zeros((len(frames), 64, 96, 3), np.float32))
    monkeypatch.setattr(selfcheck, "held_back_psnr", psnr)
    keep = np.zeros(len(planned), bool)
    keep[list(kept)] = True
    c, left = selfcheck._confirmation(scene, small, planned, keep, 1.0, synth, fits, selfcheck._Fixers(None, 1.0), cfg)
    return c, left, seen, scene


def test_kept_views_are_confirmed_on_the_photos_no_fold_held_back_and_never_from_them(monkeypatch):
    from sparself.evaluation import selfcheck

    cfg = SelfCheckConfig(pixel_weights="uniform", max_photo_loss=1.0, check_size=96)
    held = confirm_folds(12, "own")  # [[2, 6], [4, 8]]
    gains = {2: 20.5, 6: 20.5, 4: 19.8, 8: 20.3}  # +0.5, +0.5, -0.2, +0.3 dB

    def at(table):
        return lambda p, fit: table.get(p, 20.0)

    c, _, seen, scene = _confirming(monkeypatch, at(gains), cfg)
    assert c.photos == tuple(scene.frames[p].name for p in sum(held, []))
    assert c.gains == pytest.approx([0.5, 0.5, -0.2, 0.3]) and c.confirmed and c.dropped == ()
    assert len(seen) == 2 and all(not seen[k] & {scene.frames[p].name for p in h} for k, h in enumerate(held))
    c, _, _, _ = _confirming(monkeypatch, at({**gains, 8: 18.5}), cfg)  # one photo loses 1.5 dB: more than the limit
    assert not c.confirmed and min(c.gains) == pytest.approx(-1.5) and c.dropped == ()  # no kept view beside it
    c, _, _, _ = _confirming(monkeypatch, at({**gains, 8: 18.5}), replace(cfg, max_photo_loss=None))  # mean -0.18
    assert not c.confirmed
    # a gain within its spread over the photos is no evidence, as for the folds' kept views
    spread_only = replace(cfg, max_photo_loss=None, loss_within_gain=False)
    c, _, _, _ = _confirming(monkeypatch, at({**gains, 8: 19.5}), spread_only)  # +0.08 ± 0.25
    assert not c.confirmed and c.gains == pytest.approx([0.5, 0.5, -0.2, -0.5])
    c, _, _, _ = _confirming(monkeypatch, at({2: 20.6, 6: 20.4, 4: 19.9, 8: 20.5}), cfg)  # +0.35 ± 0.16
    assert c.confirmed
    # a clear gain on the mean (+0.33 ± 0.28) whose worst photo loses more than that (-0.5 dB) trades one part
    # of the capture for another: refused, under the 1 dB limit, unless that rule is off
    trade = at({2: 20.6, 6: 20.6, 4: 19.5, 8: 20.6})
    c = _confirming(monkeypatch, trade, cfg)[0]
    assert not c.confirmed
    assert selfcheck._confirm_change(c.gains).endswith("worst -0.50, a loss larger than the mean gain")
    assert _confirming(monkeypatch, trade, replace(cfg, loss_within_gain=False))[0].confirmed
    # a single photo has no spread: a gain, or none lost, confirms
    single = [selfcheck._confirmed_by(("a",), np.array([g]), cfg).confirmed for g in (0.1, 0.0, -0.1)]
    assert single == [True, True, False]


def test_a_photo_that_loses_too_much_drops_the_views_beside_it_and_the_rest_are_tested_again(monkeypatch):
    from sparself.evaluation import selfcheck
    from sparself.evaluation.selfcheck import at_check_size

    cfg = SelfCheckConfig(pixel_weights="uniform", max_photo_loss=1.0, check_size=96)
    scene = _line(12)
    planned = plan_poses(scene, PLAN)
    beside = np.flatnonzero(checkable(at_check_size(scene, cfg), planned, "own", [6]))  # between inputs 5 and 7
    far = np.flatnonzero(~checkable(at_check_size(scene, cfg), planned, "own", [2, 4, 6, 8]))
    kept = (int(beside[0]), int(far[0]), int(far[1]))
    culprit = planned[kept[0]].name

    def psnr(p, fit):  # photo 6 loses 1.5 dB only with the view beside it; the others gain 0.5
        return 18.5 if p == 6 and culprit in fit else 20.5

    c, left, _, _ = _confirming(monkeypatch, psnr, cfg, kept)
    assert c.confirmed and c.dropped == (culprit,) and c.gains == pytest.approx([0.5] * 4)
    assert c.gains_before == pytest.approx([0.5, -1.5, 0.5, 0.5])  # photos 2, 6, 4, 8
    assert list(np.flatnonzero(left)) == sorted(kept[1:])
    assert Confirmation.from_json(json.loads(json.dumps(asdict(c)))) == c
    reason = selfcheck._confirm_reason(c, 3, "3dgs", "kept")
    assert (
        "confirmed on 4 input photos no fold held back (+0.50 dB on the mean (standard error 0.00), worst +0.50) "
        "after dropping 1 of the 3 views (those beside a photo that lost more than the limit with all of them: "
        "+0.00 dB on the mean (standard error 0.50), worst -1.50)" in reason
    )
    for off in (replace(cfg, confirm_prune=False), replace(cfg, recon="nerf")):  # the NeRF's default: off
        c, left, _, _ = _confirming(monkeypatch, psnr, off, kept)
        assert not c.confirmed and c.dropped == () and left.sum() == 3
    # when the photo still loses without the views beside it, the rest are not confirmed either
    c, _, _, _ = _confirming(monkeypatch, lambda p, fit: 18.5 if p == 6 else 20.5, cfg, kept)
    assert not c.confirmed and c.dropped == (culprit,) and min(c.gains) == pytest.approx(-1.5)


def test_the_confirmation_runs_by_default_for_the_3dgs_and_the_nerf_and_as_asked_otherwise():
    from sparself.evaluation.selfcheck import confirm_on

    assert confirm_on(SelfCheckConfig(recon="3dgs")) and confirm_on(SelfCheckConfig(recon="nerf"))
    assert not confirm_on(SelfCheckConfig(recon="mpi"))
    assert not confirm_on(SelfCheckConfig(recon="nerf", confirm=False)) and confirm_on(replace(MPI, confirm=True))


def test_the_fill_control_runs_by_default_for_the_mpi_only_and_as_asked_otherwise():
    from sparself.evaluation.selfcheck import fill_control_on

    assert fill_control_on(MPI_FILLS) and not fill_control_on(MPI)
    assert not any(fill_control_on(SelfCheckConfig(recon=r)) for r in ("3dgs", "nerf"))
    assert fill_control_on(SelfCheckConfig(recon="3dgs", fill_control=True))


def test_the_pixel_weights_are_chosen_per_capture_by_default_for_the_3dgs_only_and_as_asked_otherwise():
    from sparself.evaluation.selfcheck import pixel_weights_of

    assert [pixel_weights_of(SelfCheckConfig(recon=r)) for r in ("3dgs", "mpi", "nerf")] == [
        "choose",
        "confidence",
        "confidence",
    ]
    assert pixel_weights_of(SelfCheckConfig(recon="3dgs", pixel_weights="uniform")) == "uniform"
    assert pixel_weights_of(replace(MPI, pixel_weights="choose")) == "choose"


def test_no_fold_synthesizes_from_its_held_back_photos(monkeypatch):
    from sparself.evaluation import selfcheck

    scene = _line(12)
    calls: list[tuple[set, set]] = []

    def synth(sc, targets):
        calls.append(({f.name for f in sc.frames}, {t.name for t in targets}))
        return Synthesized(_exact(sc, targets), np.full((len(targets), 64, 96), 0.9, np.float32))

    planned = plan_poses(scene, PLAN)  # four midpoints and one view past each end
    cfg = replace(MPI, ends_context=True)
    checked = selfcheck.self_check(scene, planned, synth, _exact(scene, planned), cfg, "paper")
    folds = [[scene.frames[i].name for i in held] for held in check_folds(12, MPI.gain_gap)]
    # first the views between the inputs that the ends fold fits beside its own, then each fold's views
    assert len(calls) == len(folds) + 1 == 4
    context, calls = calls[0], calls[1:]
    assert context == (calls[2][0], {f.name for f in planned if 0 <= f.index <= 11})
    assert all(sources.isdisjoint(fold) and set(fold) <= targets for (sources, targets), fold in zip(calls, folds))
    assert checked.record.validation == tuple(sum(folds, []))
    assert all(v.gain is not None for v in checked.record.views)  # the folds measure every gap and both ends
    ends = {f.name for f in stand_ins(scene, [f for f in planned if not 0 <= f.index <= 11])}
    assert calls[2][1] == ends | set(folds[2])  # the ends fold fits the stand-ins, not the views past the ends


@pytest.mark.parametrize("context", [True, False, None])
def test_the_ends_fold_fits_its_stand_ins_beside_the_views_between_the_inputs(context):
    """The views past the ends act in a fit that also has the views between the inputs (the final fit
    does): the ends fold fits those beside its stand-ins, in every one of its fits, the one without its
    stand-ins included, at one weight; no other fold fits them beyond its own. Auto (None): for the 3DGS,
    not for the MPI."""
    from sparself.evaluation import selfcheck

    scene = _line(12)
    planned = plan_poses(scene, PLAN)
    inner = {f.name for f in planned if 0 <= f.index <= 11}
    cfg = replace(MPI, ends_context=context)
    assert selfcheck.ends_context_on(replace(cfg, recon="3dgs")) == (context is not False)
    context = selfcheck.ends_context_on(cfg)
    real, seen = selfcheck.check_fits(cfg), []

    def fits(scenes):
        seen.extend(scenes)
        return real(scenes)

    selfcheck.self_check(scene, planned, _exact, _exact(scene, planned), cfg, "paper", fits=fits)
    ends = {scene.frames[0].name, scene.frames[11].name}
    of_ends = [sc for sc in seen if ends.isdisjoint(f.name for f in sc.frames)]
    others = [sc for sc in seen if not ends.isdisjoint(f.name for f in sc.frames)]
    assert of_ends and others
    assert any(not any(f.synthetic for f in sc.frames if f.name not in inner) for sc in of_ends)  # its base
    for sc in of_ends:
        weights = {f.name: f.weight for f in sc.frames if f.name in inner}
        assert weights == ({n: max(weights_of(cfg)) for n in inner} if context else {})
    fold_views = [{f.name for f in sc.frames if f.synthetic} for sc in others]
    assert all(v < inner or not v & inner for v in fold_views)  # an interior fold fits some of them, its own


def test_a_view_past_an_end_is_stood_in_for_by_the_same_extrapolation_one_input_further_in():
    scene = _line(12)  # input i at x = 0.1 i
    planned = plan_poses(scene, PLAN)
    past = [f for f in planned if not 0 <= f.index <= 11]
    assert [f.index for f in past] == [-0.2, 11.2]
    subs = stand_ins(scene, past)
    assert [f.index for f in subs] == pytest.approx([0.8, 10.2])
    np.testing.assert_allclose([f.pose.center[0] for f in subs], [0.08, 1.02], atol=1e-9)
    inside = [f for f in planned if 0 <= f.index <= 11]
    assert stand_ins(scene, inside) == inside


def test_the_weak_plan_fits_nothing_when_no_weakness_could_change_it():
    """A view for every gap and one past each end: any weakness picks the same poses, so nothing is fitted;
    with a gap left without a view (or one end visited more often than the other) the weakness decides."""

    def no_fits(scenes):
        raise AssertionError("the plan fitted a reconstruction it did not need")

    scene, every = _line(9), PlanConfig(n_mid=8, n_extra=2)
    picked = [f.index for f in weakest_plan(scene, every, no_fits, "own")]
    cands = candidate_poses(scene, every)
    rng = np.random.default_rng(0)
    assert all([f.index for f in pick_poses(cands, rng.random(len(cands)), every)] == picked for _ in range(20))
    for cfg in (PlanConfig(n_mid=7, n_extra=2), PlanConfig(n_mid=8, n_extra=1)):
        picks = {tuple(f.index for f in pick_poses(cands, rng.random(len(cands)), cfg)) for _ in range(20)}
        assert weakness_decides(cands, cfg) and len(picks) > 1


def test_the_weak_plan_avoids_the_gaps_the_check_widens():
    scene = _line(12)
    fit = _halves_disagree_at(0.2, 0.15)  # at input 2
    picked = weakest_plan(scene, PlanConfig(n_mid=2, n_extra=0), fit, "other")
    assert [f.index for f in picked] == [1.5, 2.5]  # beside held-back input 2: measured by the second fold
    assert measuring_fold(scene, picked, "other").tolist() == [1, 1]
    five = _line(5)  # one fold only, holding back input 2: the gaps beside it cannot be measured
    assert [f.index for f in weakest_plan(five, PlanConfig(n_mid=2, n_extra=0), fit, "other")] == [0.5, 3.5]


def test_kept_views_whose_gain_is_within_its_spread_over_the_held_back_photos_are_not_written():
    from sparself.evaluation.selfcheck import SelfCheckConfig, _confirmed, _Decision, _Scores

    cfg = SelfCheckConfig()
    keep = np.array([True, False])
    without = [np.array([15.0, 16.0]), np.array([17.0])]
    scores = [_Scores(w, {}) for w in without]
    noisy = [
        _Decision(keep, np.array([1.0, -1.0]), np.array([17.5, 15.7])),
        _Decision(np.zeros(2, bool), np.zeros(2), without[1]),
    ]
    decided, unclear = _confirmed(noisy, scores, cfg)  # +2.5 and -0.3 dB: mean 1.1, standard error 1.4
    assert unclear and not any(d.keep.any() for d in decided)
    assert all(np.array_equal(d.chosen, w) for d, w in zip(decided, without))  # scored as without views
    steady = [replace(noisy[0], chosen=np.array([16.2, 17.1])), noisy[1]]  # +1.2 and +1.1 dB
    decided, unclear = _confirmed(steady, scores, cfg)
    assert not unclear and decided is steady


def test_views_left_after_a_fold_is_dropped_for_a_photo_loss_must_show_a_clear_gain_on_their_own():
    from sparself.evaluation import selfcheck
    from sparself.evaluation.selfcheck import SelfCheckConfig, _Decision, _Scores

    cfg = SelfCheckConfig(max_photo_loss=1.0)
    without = [np.array([15.0, 16.0]), np.array([17.0, 18.0])]
    scores = [_Scores(w, {}) for w in without]
    folds = [selfcheck._Fold([1, 3], None, [0], [0], [], None, None, None) for _ in range(2)]  # type: ignore[arg-type]
    keep = np.array([True])
    # the first fold's view gains 3 dB where scored but costs another held-back photo 2 dB: dropped
    spoiling = _Decision(keep, np.array([3.0]), np.array([18.0, 19.0]), worst=-2.0)
    faint = _Decision(keep, np.array([0.05]), np.array([17.3, 17.8]), worst=-0.2)  # +0.3 and -0.2 dB
    assert selfcheck._confirmed([spoiling, faint], scores, cfg) == ([spoiling, faint], False)  # clear together
    decided, unclear = selfcheck._gated(folds, [spoiling, faint], scores, None, cfg)
    assert unclear and not any(d.keep.any() for d in decided)
    assert all(np.array_equal(d.chosen, w) for d, w in zip(decided, without))
    steady = replace(faint, chosen=np.array([18.0, 19.1]))  # +1.0 and +1.1 dB stand on their own
    decided, unclear = selfcheck._gated(folds, [spoiling, steady], scores, None, cfg)
    assert not unclear and [d.keep.tolist() for d in decided] == [[False], [True]]


def test_kept_together_a_fold_keeps_all_its_views_or_none_and_refits_no_subset(monkeypatch):
    from sparself.evaluation import selfcheck

    # one fold, four views: two gain at their held-back photos, two lose; together they gain +0.5 dB
    gains = np.array([1.0, -0.5, 0.8, -0.2])
    monkeypatch.setattr(selfcheck, "view_gains", lambda small, frames, change, scored: gains)
    monkeypatch.setattr(selfcheck, "held_back_psnr", lambda small, r, scored: np.array([r]))
    monkeypatch.setattr(selfcheck, "_kept_scene", lambda small, fold, views, keep, w: float(keep.sum()))
    fold = selfcheck._Fold([2], None, [0, 1, 2, 3], [2], [], None, None, [])  # type: ignore[arg-type]
    scores = selfcheck._Scores(np.array([20.0]), {1.0: np.array([20.5])})
    refits: list = []

    def fits(scenes):
        refits.extend(scenes)
        return [21.0 for _ in scenes]  # the subset alone: +1.0 dB

    def decide(**kw):
        return selfcheck._decide(None, [None] * 4, [fold], [(scores, None)], 1.0, fits, SelfCheckConfig(**kw))[0]

    each = decide()  # the gaining two, refitted alone, beat all four together
    assert each.keep.tolist() == [True, False, True, False] and refits == [2.0] and each.chosen[0] == 21.0
    refits.clear()
    together = decide(keep="together")
    assert together.keep.all() and refits == [] and together.chosen[0] == 20.5
    assert np.array_equal(together.gains, gains)  # each view's own gain is still recorded
    scores.by_weight[1.0] = np.array([19.8])  # together they lose: none is kept, whatever each gains alone
    assert not decide(keep="together").keep.any()


def test_kept_views_whose_gain_is_within_what_the_fits_seed_alone_changes_are_not_written():
    from sparself.evaluation.selfcheck import SelfCheckConfig, _confirmed, _Decision, _Scores, seed_change

    cfg = SelfCheckConfig(seed_noise=True)
    without = np.array([15.0, 16.0])
    steady = [_Decision(np.array([True, True]), np.array([1.2, 1.1]), np.array([16.2, 17.1]))]  # +1.15 dB
    # the fits without views at the second seed: +1.5 and +1.0 dB at the same photos, a 1.25 dB change
    moved = [_Scores(without, {}, other=np.array([16.5, 17.0]))]
    assert seed_change(moved) == pytest.approx(1.25)
    decided, unclear = _confirmed(steady, moved, cfg)
    assert unclear and not decided[0].keep.any()
    # a second seed that moves the fits by -0.2 dB on average: the +1.15 dB gain stands
    still = [_Scores(without, {}, other=np.array([14.7, 15.9]))]
    assert seed_change(still) == pytest.approx(0.2)
    decided, unclear = _confirmed(steady, still, cfg)
    assert not unclear and decided is steady
    assert seed_change([_Scores(without, {})]) is None  # no second seed fitted: the rule does not apply


def test_a_pair_held_back_together_leaves_a_gap_three_inputs_wide():
    scene = _line(14)
    held = trend_fold(14)
    assert held == [1, 2, 7, 8]  # neighbouring interior pairs, never an end
    idx = [f.index for f in scene.frames]
    assert widened_gaps(scene, held) == [(idx[0], idx[3])] * 2 + [(idx[6], idx[9])] * 2
    views = [replace(scene.frames[0], name=f"v{k}", index=x) for k, x in enumerate((0.5, 2.5, 3.5, 8.5, 12.5))]
    assert checkable(scene, views, "own", held).tolist() == [True, True, False, True, False]
    assert trend_fold(3) == [] and trend_fold(4) == [1, 2]
    # linear in the log of the width: from +1 dB two wide and +2 three wide, 1 - log(2) / log(1.5) one wide
    assert one_wide_gain(1.0, 2.0) == pytest.approx(-0.7095, abs=1e-4)
    assert one_wide_gain(2.0, 1.0) == pytest.approx(3.7095, abs=1e-4) and one_wide_gain(1.0, 1.0) == 1.0


def test_with_the_gap_trend_no_view_between_the_inputs_is_kept_when_its_gain_extrapolates_to_a_loss(monkeypatch):
    from sparself.evaluation import selfcheck

    scene = _line(14)
    planned = plan_poses(scene, PlanConfig(n_mid=8, n_extra=2))
    past = beyond(scene, planned)
    sources: list[tuple[set, set]] = []

    def synth(sc, targets):
        sources.append(({f.name for f in sc.frames}, {t.name for t in targets}))
        return Synthesized(_exact(sc, targets), np.full((len(targets), 64, 96), 0.9, np.float32))

    def check(cfg):
        return selfcheck.self_check(scene, planned, synth, _exact(scene, planned), cfg, "paper").record

    plain = replace(MPI, gain_gap="own", fixer=False)
    before = check(plain)
    assert before.gap_trend is None and any(v.kept for v, p in zip(before.views, past) if not p)
    extrapolated: list[tuple[float, float]] = []
    monkeypatch.setattr(selfcheck, "one_wide_gain", lambda two, three: extrapolated.append((two, three)) or -1.0)
    sources.clear()
    rec = check(replace(plain, gap_trend=True))
    pairs = {scene.frames[i].name for i in trend_fold(14)}
    # the gap-trend fold synthesizes its views without its held-back photos, and (no fixer) not those photos
    trend_calls = [targets for made, targets in sources if made.isdisjoint(pairs)]
    assert len(trend_calls) == 1 and trend_calls[0].isdisjoint(pairs)
    names = {f.name for f in scene.frames}
    assert all(targets.isdisjoint(names - made) for made, targets in sources)  # no fixer: no held-back photo made
    assert rec.gap_trend == GapTrend(*extrapolated[0], -1.0, False)
    # no view between the inputs is kept; those past the ends keep the ends fold's decision
    assert not any(v.kept for v, p in zip(rec.views, past) if not p)
    assert [v.kept for v, p in zip(rec.views, past) if p] == [v.kept for v, p in zip(before.views, past) if p]
    assert "none between the inputs is kept" in rec.reason
    monkeypatch.setattr(selfcheck, "one_wide_gain", lambda two, three: 1.0)
    kept = check(replace(plain, gap_trend=True))  # the extrapolated gain pays: every decision stands
    assert kept.gap_trend is not None and kept.gap_trend.interior_kept and kept.views == before.views


def test_a_fold_whose_views_spoil_a_held_back_photo_far_from_them_keeps_none_with_a_photo_loss_limit(monkeypatch):
    from sparself.evaluation import selfcheck
    from sparself.evaluation.weighting import ValidationViews

    # a fold holding back photos 1, 5 and 9; its one view is nearest photo 1, where it is scored
    views = ValidationViews(np.zeros((1, 2, 2, 3), np.float32), None, [])
    fold = selfcheck._Fold([1, 5, 9], "base", [0], [1], [], views, None, None)  # type: ignore[arg-type]
    psnr = {"base": np.array([20.0, 21.0, 22.0]), "with 1.0": np.array([21.0, 20.8, 19.5])}
    monkeypatch.setattr(selfcheck, "weight_scenes", lambda small, frames, v, weights, held: list(weights))
    monkeypatch.setattr(selfcheck, "held_back_psnr", lambda small, r, held: psnr[r][[[1, 5, 9].index(h) for h in held]])
    cfg = SelfCheckConfig(pixel_weights="uniform", check_weights=(1.0,))
    [(scores, _)] = selfcheck._scores(None, [fold], lambda scenes: [f"with {w}" for w in scenes], None, cfg)
    # the view gains +1 dB where it is scored, and photo 9, nearest no view, loses 2.5 dB
    assert scores.by_weight[1.0] - scores.without == pytest.approx([1.0]) and scores.worst[1.0] == pytest.approx(-2.5)
    kept = [selfcheck._settle(np.array([True]), np.array([1.0]), scores, 1.0, None, cfg, fold)]
    assert kept[0].keep.all() and kept[0].worst == pytest.approx(-2.5)

    def spared(limit):
        return selfcheck._spared([fold], kept, [scores], replace(cfg, max_photo_loss=limit))[0]

    assert spared(None) is kept[0] and spared(3.0) is kept[0]
    dropped = spared(1.0)
    assert not dropped.keep.any() and dropped.chosen == pytest.approx([20.0]) and dropped.gains == pytest.approx([1.0])
    # a subset refitted alone that scores higher is judged by its own fit: there photo 9 loses only 0.1 dB
    subset = selfcheck._settle(np.array([True]), np.array([1.0]), scores, 1.0, np.array([21.5, 21.0, 21.9]), cfg, fold)
    assert subset.chosen == pytest.approx([21.5]) and subset.worst == pytest.approx(-0.1)
    assert selfcheck._spared([fold], [subset], [scores], replace(cfg, max_photo_loss=1.0))[0] is subset


def test_the_self_check_record_round_trips_through_json():
    views = (ViewCheck("n", 1.5, 0.3, True), ViewCheck("m", 2.5, None, False))
    rec = SelfCheck("3dgs", "weak", ("a", "b"), 20.5, ((0.5, 21.0), (1.0, 20.0)), 21.5, 0.5, views, "r")
    assert SelfCheck.from_json(json.loads(json.dumps(rec.to_json()))) == rec
    seeded = replace(
        rec,
        psnr_other_seed=19.75,
        gap_trend=GapTrend(1.25, 2.0, -0.03, False),
        confirmation=Confirmation(("c", "d"), (0.25, -1.5), False),
        pixel_weights="uniform",
        psnr_by_pixel_weights=(("confidence", 21.25), ("uniform", 21.5)),
        fill_control=FillControl(("a", "e"), (22.5, 19.0), (22.0, 19.25), ((21.5, 21.25), (19.5, 19.0)), ("m",)),
    )
    assert SelfCheck.from_json(json.loads(json.dumps(seeded.to_json()))) == seeded
    assert rec.kept == ("n",)


def test_a_batch_manifest_sets_the_self_check_per_capture():
    from sparself.batch_units import densify_configs

    [(_, cfg)] = densify_configs(pipeline.DensifyConfig(), {"recon": "mpi", "check_steps": 50, "n_mid": 3, "epochs": 2})
    assert (cfg.check.recon, cfg.check.check_steps, cfg.plan.n_mid, cfg.train.epochs) == ("mpi", 50, 3, 2)


def test_a_bad_self_check_setting_is_one_line_before_anything_runs(tmp_path, capsys):
    from sparself import cli

    write_scene(small_plane_scene(), tmp_path / "cap")
    assert cli.main(["densify", str(tmp_path / "cap"), "--out", str(tmp_path / "o"), "--check-weights", "0"]) != 0
    err = capsys.readouterr().err.strip()
    assert "check_weights" in err and "\n" not in err and not (tmp_path / "o").exists()


def test_fits_of_photos_alone_are_made_once_per_capture_and_views_are_always_fitted():
    from sparself.evaluation.selfcheck import remembering

    scene = _line(6)
    calls: list[int] = []

    def fits(scenes):
        calls.append(len(scenes))
        return [object() for _ in scenes]

    fits_once = remembering(fits)
    views = scene.subset([0, 1, 2])
    views.frames[1] = replace(views.frames[1], synthetic=True)
    a = fits_once([scene.subset([0, 1]), scene.subset([2, 3]), views])
    b = fits_once([scene.subset([2, 3]), views, scene.subset([0, 1])])
    assert calls == [3, 1] and a[0] is b[2] and a[1] is b[0] and a[2] is not b[1]
    weighted = scene.subset([0, 1])
    weighted.frames[0] = replace(weighted.frames[0], weight=0.5)
    assert fits_once([weighted])[0] is not a[0] and calls == [3, 1, 1]


def test_the_automatic_weights_are_one_for_the_3dgs_and_two_otherwise_and_a_named_grid_is_followed():
    from sparself.core.options import add_options, from_args

    assert weights_of(SelfCheckConfig(recon="3dgs")) == (1.0,)
    assert weights_of(SelfCheckConfig(recon="mpi")) == weights_of(SelfCheckConfig(recon="nerf")) == (0.5, 1.0)
    assert weights_of(SelfCheckConfig(recon="3dgs", check_weights=(0.25, 1.0))) == (0.25, 1.0)
    p = argparse.ArgumentParser()
    add_options(p, SelfCheckConfig)
    assert from_args(SelfCheckConfig, p.parse_args(["--check-weights", "auto"])).check_weights is None
    assert from_args(SelfCheckConfig, p.parse_args(["--check-weights", "0.5,1"])).check_weights == (0.5, 1.0)
    with pytest.raises(SystemExit):
        p.parse_args(["--check-weights", "half"])


@pytest.mark.parametrize("fixer", [True, False])
def test_the_fit_on_every_input_is_fitted_once_beside_the_folds_fits_without_views(fixer):
    """The fixer merges the written views with the render of the fit on every input: that fit runs in the
    batch of the folds' fits without views (where an odd number of folds leaves a worker free), never
    again, and is what the check hands on; without the fixer it is not fitted at all."""
    from sparself.evaluation import selfcheck

    scene = _line(12)
    planned = plan_poses(scene, PLAN)
    cfg = replace(MPI, fixer=fixer)
    real, batches = selfcheck.check_fits(cfg), []

    def fits(scenes):
        batches.append([{f.name for f in sc.frames} for sc in scenes])
        out = real(scenes)
        batches[-1] = list(zip(batches[-1], out))
        return out

    checked = selfcheck.self_check(scene, planned, _exact, _exact(scene, planned), cfg, "paper", fits=fits)
    every = {f.name for f in scene.frames}
    whole = [(k, r) for k, batch in enumerate(batches) for names, r in batch if names == every]
    folds = len(check_folds(12, MPI.gain_gap))
    assert [len(b) for b in batches[:1]] == [folds + fixer]
    assert [k for k, _ in whole] == ([0] if fixer else [])
    if fixer and checked.fixer is not None:
        assert checked.reference is whole[0][1]


@pytest.mark.parametrize("recon, auto", [("nerf", "paper"), ("3dgs", "weak"), ("mpi", "weak")])
def test_the_automatic_plan_is_the_papers_for_the_nerf_and_the_weak_one_otherwise(monkeypatch, recon, auto):
    """A NeRF is given the paper's poses (views past both ends), the others views where their fits are weak;
    a plan the user names is taken as named; the decision records the plan used."""
    from sparself.evaluation import selfcheck

    scene, seen = _line(12), []
    paper = plan_poses(scene, PLAN)
    weak = paper[1:3]
    monkeypatch.setattr(selfcheck, "weakest_plan", lambda *a, **k: weak)
    monkeypatch.setattr(selfcheck, "self_check", lambda inputs, targets, *a: seen.append((targets, a[-3])))
    for mode, want in [("auto", auto), ("weak", "weak"), ("paper", "paper")]:
        cfg = SelfCheckConfig(recon=recon, plan_mode=mode)
        assert selfcheck.plan_of(cfg) == want
        targets, _, _ = selfcheck.checked_views(scene, paper, PLAN, _exact, cfg, fits=lambda scenes: [])
        assert targets == (paper if want == "paper" else weak) and seen[-1] == (targets, want)


def test_densify_fits_a_scene_of_real_photos_once_per_check(monkeypatch):
    """A scene of real photos the check asks for twice (the confirmation's bases, when a second way of
    weighting the pixels decides) is fitted once."""
    from sparself.evaluation import selfcheck

    fitted = []
    monkeypatch.setattr(
        selfcheck, "check_fits", lambda cfg, pool=None: lambda scenes: [fitted.append(sc) or object() for sc in scenes]
    )
    monkeypatch.setattr(selfcheck, "self_check", lambda inputs, *a: [a[5]([inputs.subset(range(3))])[0] for _ in "ab"])
    scene = _line(6)
    planned = plan_poses(scene, PLAN)
    _, both, _ = selfcheck.checked_views(scene, planned, PLAN, _exact, replace(MPI, plan_mode="paper"))
    assert both[0] is both[1] and len(fitted) == 1


def test_a_stopped_densify_resumes_from_its_fits_to_the_same_scene(tmp_path, monkeypatch):
    """A densify stopped in its self-check keeps the fits it finished beside its output, and ``resume`` fits only
    the others and writes what a run never stopped writes."""
    from sparself.core.outputs import work_path
    from sparself.recon import pool

    fit, fitted = pool._fitted, []

    def counted(fitters, scenes, within):
        if stop_at and len(fitted) >= stop_at:
            raise KeyboardInterrupt
        fitted.extend(scenes)
        return fit(fitters, scenes, within)

    monkeypatch.setattr(pool, "_fitted", counted)
    stop_at = 0
    whole = _densify(tmp_path / "whole", monkeypatch, _exact)
    total, fitted[:] = len(fitted), []
    assert total > 4 and not work_path(tmp_path / "whole" / "out").exists()  # removed once the scene is written
    stop_at = 3
    with pytest.raises(KeyboardInterrupt):
        _densify(tmp_path / "stopped", monkeypatch, _exact)
    out = tmp_path / "stopped" / "out"
    kept = sorted((work_path(out) / "fits").glob("*.pkl"))
    assert not out.exists() and len(kept) == len(fitted) >= 3  # nothing written, every finished fit kept
    before, stop_at, fitted[:] = len(kept), 0, []
    resumed = _densify(tmp_path / "stopped", monkeypatch, _exact, resume=True)
    assert len(fitted) == total - before and not work_path(out).exists()
    assert read_selfcheck(out / "scene") == read_selfcheck(tmp_path / "whole" / "out" / "scene")
    assert [f.name for f in resumed.frames] == [f.name for f in whole.frames]
    for a, b in zip(resumed.frames, whole.frames):
        assert same_content(a.image, b.image) and same_content(a.confidence, b.confidence)
