"""Render -> fix -> refit: after the first round, the self-check's folds are fitted with their views, a new
fixer merges the network's views with those fits' renders, and a round is kept only while it raises the
photos the folds held back; the confirmation and the written views go through the kept rounds alike."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace

import numpy as np
import pytest

from planescene import plane_scene
from sparself.capture.io.dense import FixerCheck, FixRound, SelfCheck, ViewCheck
from sparself.core.content import same_content
from sparself.evaluation import selfcheck
from sparself.evaluation.fixing import FixerFit
from sparself.evaluation.selfcheck import SelfCheckConfig
from sparself.evaluation.weighting import ValidationViews
from sparself.synthesis.plan import PlanConfig, plan_poses

CFG = SelfCheckConfig(recon="3dgs", fix_rounds=4, check_size=96)


@dataclass(frozen=True)
class _Fit:
    value: float  # every pixel of the views it was fitted with, and so of its renders


def _views(value: float) -> ValidationViews:
    return ValidationViews(np.full((1, 2, 2, 3), value, np.float32), None, [])


def _folds(raws: list[float], first: float) -> list:
    """Two one-view folds whose network views are ``raws`` and whose first round added ``first``."""
    return [
        selfcheck._Fold(
            [2 + 2 * k], _Fit(0.0), [k], [2 + 2 * k], [f"v{k}"], _views(r + first), np.zeros(1), "pairs", raw=_views(r)
        )
        for k, r in enumerate(raws)
    ]


def _rigged(monkeypatch, used=lambda round_: True):
    """Fits that render the value of the views they were fitted with; a photo's PSNR peaks where that value
    is 0.5; each round's fixer adds its render to the network's view (``used(round)``: whether it beats
    both; the one for fold k records (k, the view it merges)). Returns (the fits, the scenes of each call to
    them, per round the pairs its fixer was trained on as (held-back photo, render), the fixers' merges)."""
    fitted, trained, merged = [], [], []
    monkeypatch.setattr(
        selfcheck, "_fold_scene", lambda small, f, w, cfg: (f.held[0], float(f.synthesized.images.mean()), w)
    )
    monkeypatch.setattr(
        selfcheck, "renders", lambda r, small, frames: np.full((len(frames), 2, 2, 3), r.value, np.float32)
    )
    monkeypatch.setattr(
        selfcheck, "held_back_psnr", lambda small, r, held: np.array([30 - 10 * abs(r.value - 0.5) for _ in held])
    )
    monkeypatch.setattr(selfcheck, "refit_pairs", lambda pairs, small, held, r: (held[0], r.value))
    monkeypatch.setattr(selfcheck, "fixed", lambda fx, views, ref, conf: fx(views, ref))

    def merging(k):
        def fx(v, ref):
            merged.append((k, float(v.mean())))
            return v + ref

        return fx

    def fold_fixers(pairs, cfg):
        trained.append(pairs)
        each = [merging(k) for k in range(len(pairs))] if used(len(trained) + 1) else []
        fx = (lambda v, ref: v + ref) if each else None
        return FixerFit(fx, FixerCheck(("a", "b"), 20.0, 21.0, 22.0, fx is not None)), each

    def fits(scenes):
        fitted.append(scenes)
        return [_Fit(v) for _, v, _ in scenes]

    monkeypatch.setattr(selfcheck, "_fold_fixers", fold_fixers)
    return fits, fitted, trained, merged


def test_a_round_is_kept_while_it_raises_the_held_back_photos_and_merges_the_networks_views_again(monkeypatch):
    fits, fitted, trained, merged = _rigged(monkeypatch)
    first = FixerFit(None, FixerCheck(("a", "b"), 20.0, 21.0, 20.5, False))
    folds, fixers, done = selfcheck._refixed(None, _folds([0.2, 0.22], 0.05), first, fits, CFG)
    # round 2 merges the raw views with the renders of the fits with round 1's views: 0.2 + 0.25, 0.22 + 0.27,
    # nearer the peak (kept); round 3 would give 0.65 and 0.71, past it (not kept): the rounds stop there
    assert [f.synthesized.images.mean() for f in folds] == pytest.approx([0.45, 0.49])
    assert [r.kept for r in fixers.rounds] == [True, False] and len(fixers.later) == 1 and fixers.first is None
    assert fixers.rounds[0].psnr_before == pytest.approx(30 - 10 * 0.24) and fixers.rounds[
        0
    ].psnr_after == pytest.approx(30 - 10 * 0.03)
    # each round's fixer learnt from the renders of the fits with the previous round's views, at the held-back photos
    assert trained == [
        [(2, pytest.approx(0.25)), (4, pytest.approx(0.27))],
        [(2, pytest.approx(0.45)), (4, pytest.approx(0.49))],
    ]
    assert [len(s) for s in fitted] == [2, 2, 2] and {w for s in fitted for _, _, w in s} == {1.0}
    assert fixers.last is fixers.later[0]
    # each fold's network view is merged by the fixer scored on that fold (trained on the others' photos)
    assert merged[:2] == [(0, pytest.approx(0.2)), (1, pytest.approx(0.22))]
    # handed on for the scoring: the kept round's fold scenes and their fits, not the refit that was not kept
    assert [sc for sc, _ in done] == fitted[1] and [r.value for _, r in done] == pytest.approx([0.45, 0.49])


def test_one_round_fits_nothing_more_and_an_unused_fixer_ends_the_rounds(monkeypatch):
    fits, fitted, _, _ = _rigged(monkeypatch, used=lambda round_: round_ > 2)
    first = FixerFit(None, FixerCheck(("a", "b"), 20.0, 21.0, 20.5, False))
    folds = _folds([0.2, 0.22], 0.05)
    same, fixers, done = selfcheck._refixed(None, folds, first, fits, replace(CFG, fix_rounds=1))
    assert same is folds and fixers.rounds == () and fitted == [] and done == []
    same, fixers, _ = selfcheck._refixed(None, folds, None, fits, CFG)  # no fixer at all (off, or no pairs)
    assert same is folds and fitted == []
    same, fixers, done = selfcheck._refixed(None, folds, first, fits, CFG)
    assert same is folds and fixers.later == () and len(fitted) == 1
    assert [sc for sc, _ in done] == fitted[0]  # the folds with their first round's views, fitted once
    assert fixers.rounds == (
        FixRound(FixerCheck(("a", "b"), 20.0, 21.0, 22.0, False), pytest.approx(27.6), None, False),
    )
    assert "round 2's fixer did not beat both" in selfcheck._rounds_reason(fixers.rounds)


def test_the_confirmations_and_the_written_views_go_through_the_kept_rounds_from_the_networks_views(monkeypatch):
    fits, fitted, _, _ = _rigged(monkeypatch)
    monkeypatch.setattr(
        selfcheck, "_replay_scene", lambda small, job, images, w, cfg: (job.held, float(images.mean()), w)
    )
    fixers = selfcheck._Fixers(None, 0.5, later=(lambda v, ref: v + ref, lambda v, ref: v * ref))
    jobs = [
        selfcheck._Replay(
            ["v"], np.full((1, 2, 2, 3), r, np.float32), None, np.full((1, 2, 2, 3), r + 0.1, np.float32), h, _Fit(0)
        )
        for r, h in ((0.2, [2]), (0.3, []))
    ]
    out = selfcheck._replayed(fixers, None, jobs, fits, CFG)
    # round 2: raw + render of the fit with round 1's views; round 3: raw * render of the fit with round 2's
    assert [float(im.mean()) for im, _ in out] == pytest.approx([0.2 * 0.5, 0.3 * 0.7])
    assert [r.value for _, r in out] == pytest.approx([0.5, 0.7])
    assert fitted == [
        [([2], pytest.approx(0.3), 0.5), ([], pytest.approx(0.4), 0.5)],
        [([2], pytest.approx(0.5), 0.5), ([], pytest.approx(0.7), 0.5)],
    ]
    none = selfcheck._replayed(selfcheck._Fixers(None, 1.0), None, jobs, fits, CFG)
    assert [im is j.images and r is j.base for (im, r), j in zip(none, jobs)] == [True, True] and len(fitted) == 2


def test_a_later_rounds_refit_holds_its_photos_back_and_fits_the_views_at_the_rounds_weight():
    scene = plane_scene(xs=tuple(0.1 * i for i in range(12)))
    small = selfcheck.at_check_size(scene, CFG)
    planned = plan_poses(scene, PlanConfig(n_mid=4, n_extra=2))[:2]
    images = np.full((2, 64, 96, 3), 0.5, np.float32)
    job = selfcheck._Replay(planned, images, None, images, [2, 6], _Fit(0.0))
    base = selfcheck.check_fits(replace(CFG, recon="mpi"))([small.without([2, 6])])[0]
    sc = selfcheck._replay_scene(small, replace(job, base=base), images, 0.7, CFG)
    names = {f.name for f in sc.frames if not f.synthetic}
    assert names == {f.name for k, f in enumerate(small.frames) if k not in (2, 6)}
    assert sorted(f.name for f in sc.frames if f.synthetic) == sorted(f.name for f in planned)
    assert {f.weight for f in sc.frames if f.synthetic} == {0.7}
    whole = selfcheck._replay_scene(small, replace(job, held=[], base=base), images, 0.7, CFG)
    assert len([f for f in whole.frames if not f.synthetic]) == len(small)


def test_the_scoring_takes_the_rounds_fit_of_an_equal_scene_and_fits_every_other():
    small = selfcheck.at_check_size(plane_scene(xs=tuple(0.1 * i for i in range(6))), CFG)
    planned = plan_poses(small, PlanConfig(n_mid=2, n_extra=0))
    images = np.full((2, small.frames[0].image.shape[0], small.frames[0].image.shape[1], 3), 0.5, np.float32)
    conf = np.ones(images.shape[:3], np.float32)
    views = ValidationViews(images, conf, [])
    [done] = selfcheck.weight_scenes(small, planned, views, [1.0], [2])
    # the same content built again from copies: equal, though no array is the same object
    views_again = ValidationViews(images.copy(), conf.copy(), [])
    [again] = selfcheck.weight_scenes(small, planned, views_again, [1.0], [2])
    brighter = images.copy()
    brighter[1, 0, 0, 0] += 0.25
    [one_pixel] = selfcheck.weight_scenes(small, planned, ValidationViews(brighter, conf, []), [1.0], [2])
    [heavier] = selfcheck.weight_scenes(small, planned, views, [0.5], [2])
    [other_held] = selfcheck.weight_scenes(small, planned, views, [1.0], [3])
    asked = []

    def fits(scenes):
        asked.append(scenes)
        return [_Fit(float(k)) for k in range(len(scenes))]

    out = selfcheck.reusing(fits, [(done, _Fit(-1.0))])([one_pixel, again, heavier, other_held])
    assert [r.value for r in out] == [0.0, -1.0, 1.0, 2.0]
    assert asked == [[one_pixel, heavier, other_held]]
    assert selfcheck.reusing(fits, [])([again])[0].value == 0.0  # nothing handed on: every scene is fitted
    assert not same_content(np.zeros(2, np.float32), np.zeros(2, np.float64))
    assert same_content({"a": (1, np.ones(2))}, {"a": (1, np.ones(2))})


def test_the_rounds_record_round_trips_through_sparself_json_and_is_said_in_the_reason():
    rounds = (
        FixRound(FixerCheck(("a",), 20.0, 21.0, 22.0, True), 21.5, 22.25, True),
        FixRound(FixerCheck(("a",), 20.0, 22.0, 22.1, True), 22.25, 22.2, False),
    )
    rec = SelfCheck(
        "3dgs", "weak", ("a",), 20.5, ((1.0, 21.0),), None, 1.0, (ViewCheck("n", 1.5, 0.3, True),), "r", rounds=rounds
    )
    assert SelfCheck.from_json(json.loads(json.dumps(rec.to_json()))) == rec
    said = selfcheck._rounds_reason(rounds)
    assert "round 2 moved the folds' scored photos 21.50 -> 22.25 dB (kept)" in said
    assert "round 3 moved the folds' scored photos 22.25 -> 22.20 dB (not kept)" in said
    assert selfcheck._rounds_reason(()) == ""


def test_fix_rounds_must_be_at_least_one():
    from sparself.core.errors import ConfigError

    with pytest.raises(ConfigError, match="fix_rounds"):
        replace(CFG, fix_rounds=0).validate()


def test_the_written_views_are_the_kept_ones_through_every_kept_round_and_hand_on_the_last_fixer(monkeypatch):
    fits, fitted, _, _ = _rigged(monkeypatch)
    monkeypatch.setattr(
        selfcheck, "_replay_scene", lambda small, job, images, w, cfg: (job.held, float(images.mean()), w)
    )
    planned = ["a", "b", "c"]
    raw = np.stack([np.full((2, 2, 3), v, np.float32) for v in (0.1, 0.2, 0.3)])
    keep = np.array([True, False, True])
    rec = SelfCheck("3dgs", "weak", ("p",), 20.0, ((1.0, 21.0),), 21.0, 1.0, (), "r")
    fold = _folds([0.2], 0.0)[0]
    last = lambda v, ref: v * ref  # noqa: E731
    fixers = selfcheck._Fixers(lambda v, ref: v + ref, 1.0, later=(last,))
    cfg = replace(CFG, pixel_weights="uniform")
    out = selfcheck._written(None, planned, raw, keep, rec, fold, fixers, _Fit(0.05), fits, cfg)
    # first round: raw + the render of the fit on every input (0.05); the later round: raw * the render of that
    # fit refitted with the kept views of the first round (their mean: (0.15 + 0.35) / 2)
    assert out.frames == ["a", "c"] and [float(im.mean()) for im in out.images] == pytest.approx([0.025, 0.075])
    assert out.fixer is last and out.reference == _Fit(pytest.approx(0.25)) and len(fitted) == 1
    assert out.confidence.shape == (2, 2, 2) and np.all(out.confidence == 1.0)
    none = selfcheck._written(None, planned, raw, np.zeros(3, bool), rec, fold, fixers, _Fit(0.05), fits, cfg)
    assert len(none.frames) == 0 and len(fitted) == 1  # nothing kept: nothing refitted
