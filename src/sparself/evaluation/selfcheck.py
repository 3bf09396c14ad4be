"""The densify self-check: synthesized views are kept only where they make the chosen reconstruction better
at held-back *input* photos, so a densified capture is never worse than the N photos alone (on that check).

* **Look before synthesizing** (:func:`weakest_plan`): two fits on complementary halves of the inputs (every
  other view) are rendered at candidate poses (:func:`sparself.synthesis.plan.candidate_poses`); where they
  disagree most, the reconstruction is weakest, and that is where views are planned.
* **Keep only what pays** (:func:`self_check`): every ``VALIDATION_EVERY``-th interior input is held back
  (:mod:`sparself.evaluation.weighting`), the views are synthesized again without those photos, and the
  reconstructor is fitted on the rest without and with them at each synthetic-frame weight. A view's gain is
  the PSNR change at the held-back inputs nearest to it; views that gain are kept (refitted alone to confirm),
  and when nothing beats the fit without views, none is written. Only views outside every held-back input's
  widened gap (between its two neighbours) are checked, planned or kept (:func:`checkable`): a view there
  would fill a hole twice as wide as any the final fit, which has that input, ever has.
* **Fix before checking** (:mod:`sparself.evaluation.fixing`): a small network trained on the held-back
  inputs merges each view with the render of the fit without it, pixel by pixel; the merged views replace
  the network's when they beat both the views and the render on those photos (each scored by a fixer that
  did not train on it).
* **Per pixel** (:func:`informative_confidence`): where a view agrees with the render of the fit without it
  within ``agree_within``, it adds nothing that reconstruction does not already make, so its confidence is
  lowered there (written as the exported mask, so gsplat/nerfstudio users get the same effect).

The self-check's fits run at ``check_size`` pixels with ``check_steps`` optimisation steps: it compares fits
with each other, so they need not be the user's final fit, only alike.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Callable, Literal

import numpy as np
import torch

from sparself.capture.images import resize_images
from sparself.capture.io.dense import SelfCheck, ViewCheck
from sparself.capture.scene import Frame, Scene, preloaded
from sparself.core.errors import ConfigError
from sparself.core.options import check_choices, option
from sparself.evaluation.fixing import FixerFit, fixed, held_back_fixer
from sparself.evaluation.instruments import SynthFn, images_and_confidence, renders
from sparself.evaluation.weighting import (
    ValidationViews,
    held_back_psnr,
    validation_inputs,
    validation_split,
    validation_views,
    weight_scores,
)
from sparself.model.fixer import Fixer
from sparself.recon import Renderer, get_reconstructor
from sparself.synthesis.plan import PlanConfig, candidate_poses, pick_poses
from sparself.synthesis.synthesize import Synthesized

log = logging.getLogger(__name__)

FIXER_STEPS = 300  # optimisation steps of each fixer fit (a few seconds at the check size)
BLUR = 5  # px: the view-minus-render difference is averaged over this window before it is compared


@dataclass
class SelfCheckConfig:
    """How ``densify`` checks its views against a reconstruction (each field's help is its documentation)."""

    recon: Literal["3dgs", "nerf", "mpi", "none"] = option(
        "3dgs",
        "reconstruction the views must improve: plan where it is weak, keep only views that raise its PSNR on "
        "held-back input photos (none: the paper's plan, every view kept, no fit)",
    )
    plan_mode: Literal["weak", "paper"] = option(
        "weak",
        "where views go: where fits on complementary halves of the inputs disagree most (weak), or the "
        "paper's midpoints and extrapolations (paper; always with --recon none)",
        flag="--plan",
    )
    check_size: int = option(
        64, "long side in px of the self-check's fits (a CPU 3DGS step costs about 4x more at twice the side)"
    )
    check_steps: int | None = option(
        300, "optimisation steps of each self-check fit (auto: the reconstructor's own, slower)"
    )
    check_weights: tuple[float, ...] = option(
        (0.5, 1.0), "synthetic-frame loss weights tried (one fit each on the inputs minus the held-back ones)"
    )
    min_gain: float = option(0.0, "dB a view must add at its held-back inputs to be kept")
    agree_within: float = option(
        0.03,
        "mean absolute difference (0..1) within which a synthesized pixel agrees with the render of the fit "
        "without it; its confidence is lowered there (0: never)",
    )
    agree_weight: float = option(0.3, "the factor the confidence of such agreeing pixels is multiplied by")
    check_seed: int = option(0, "seed of the self-check's fits")
    fixer: bool = option(
        True,
        "merge each view with the render of the fit without it, pixel by pixel, by a small network trained on "
        "the held-back input photos (used only when it beats both the views and the render there)",
    )

    def validate(self) -> None:
        check_choices(self)
        if self.check_size < 8 or (self.check_steps is not None and self.check_steps < 1):
            raise ConfigError(
                f"check_size must be >= 8 and check_steps >= 1, got {self.check_size}, {self.check_steps}"
            )
        if not self.check_weights or min(self.check_weights) <= 0:
            raise ConfigError(f"check_weights must be one or more weights > 0, got {self.check_weights}")
        if self.agree_within < 0 or not 0 <= self.agree_weight <= 1:
            raise ConfigError(
                f"agree_within must be >= 0 and agree_weight in [0, 1], got {self.agree_within}, {self.agree_weight}"
            )


@dataclass
class Checked:
    """What densify writes: the kept planned frames, their images (T, H, W, 3) and exported confidence
    (T, H, W; the synthetic-frame weight and the per-pixel lowering folded in), and the decision."""

    frames: list[Frame]
    images: np.ndarray
    confidence: np.ndarray | None
    record: SelfCheck | None  # None: not checked (recon none)
    fixer: Fixer | None = None  # the fixer the written views went through (None: not used)
    reference: Renderer | None = None  # the fit on all inputs at the check size whose renders it merged in


def check_fit(cfg: SelfCheckConfig) -> Callable[[Scene], Renderer]:
    """fit(scene) -> renderer for ``cfg.recon`` with the self-check's steps and seed."""
    fit = get_reconstructor(cfg.recon)
    kw: dict = {} if cfg.recon == "mpi" else {"seed": cfg.check_seed, "progress": False}
    if cfg.check_steps is not None and cfg.recon != "mpi":
        kw["steps"] = cfg.check_steps
        if cfg.recon == "3dgs" and _cpu_splatting():
            kw["min_steps_per_view"] = 0  # the CPU path raises steps to 60 per view otherwise
    return lambda sc: fit(sc, **kw)


def _cpu_splatting() -> bool:
    from sparself.recon.gsplat import available

    return not available()[0]


def check_cameras(scene: Scene, cfg: SelfCheckConfig) -> Scene:
    """The scene with its cameras at ``cfg.check_size`` (never enlarged); no image is read."""
    side = max(max(c.width, c.height) for c in scene.cameras.values())
    return scene.resized(cfg.check_size) if side > cfg.check_size else scene


def at_check_size(scene: Scene, cfg: SelfCheckConfig) -> Scene:
    """The scene with images in memory at ``cfg.check_size`` (never enlarged)."""
    return preloaded(check_cameras(scene, cfg))


def checkable(inputs: Scene, planned: list[Frame]) -> np.ndarray:
    """(T,) bool: the planned views outside every held-back input's widened gap, the open interval between
    the indices of the inputs on either side of it (``inputs`` in path order; :func:`validation_inputs`).

    A view inside one is measured where the check's fit lacks a photo the final fit has: its gain there is a
    hole the final fit never has, so it does not carry over (and it would blur the others' gains there)."""
    idx = [f.index for f in inputs.frames]
    gaps = [sorted((idx[p - 1], idx[p + 1])) for p in validation_inputs(len(inputs))]
    return np.array([not any(a < f.index < b for a, b in gaps) for f in planned], bool)


def weakest_plan(inputs: Scene, plan: PlanConfig, fit: Callable[[Scene], Renderer]) -> list[Frame]:
    """``plan.n_mid`` gaps and ``plan.n_extra`` extrapolations where two fits on complementary halves of
    ``inputs`` (even and odd positions; a scene in path order) disagree most (mean absolute difference of
    their renders), at the poses of :func:`sparself.synthesis.plan.candidate_poses` that are
    :func:`checkable` (so the self-check can measure every planned view) when there are any."""
    cands = candidate_poses(inputs, replace(plan, order="capture"))
    ok = checkable(inputs, [c.frame for c in cands])
    if ok.any():  # else every view is planned unchecked, and the self-check says it keeps none
        cands = [c for c, k in zip(cands, ok) if k]
    frames = [c.frame for c in cands]
    a, b = (renders(fit(inputs.subset(range(k, len(inputs), 2))), inputs, frames) for k in (0, 1))
    weak = np.abs(a - b).mean(axis=(1, 2, 3))
    picked = pick_poses(cands, weak, plan)
    log.info(
        "plan: %d views where halves of the inputs disagree most (%.4f .. %.4f; candidates %.4f .. %.4f)",
        len(picked),
        min(weak[frames.index(f)] for f in picked),
        max(weak[frames.index(f)] for f in picked),
        weak.min(),
        weak.max(),
    )
    return picked


def informative_confidence(
    images: np.ndarray, confidence: np.ndarray | None, reference: np.ndarray, cfg: SelfCheckConfig
) -> np.ndarray:
    """Each view's confidence (T, H, W; ones when None) times ``cfg.agree_weight`` where it agrees with
    ``reference`` (the render of a fit without it, same size) within ``cfg.agree_within`` (mean absolute
    difference over the colour channels and a BLUR-px window), rising linearly to 1 at twice that."""
    conf = np.ones(images.shape[:3], np.float32) if confidence is None else np.asarray(confidence, np.float32)
    if cfg.agree_within <= 0:
        return conf
    raw = torch.from_numpy(np.abs(np.asarray(images, np.float32) - reference).mean(-1))[:, None]
    diff = torch.nn.functional.avg_pool2d(raw, BLUR, 1, BLUR // 2, count_include_pad=False)[:, 0].numpy()
    tau = cfg.agree_within
    factor = cfg.agree_weight + (1.0 - cfg.agree_weight) * np.clip((diff - tau) / tau, 0.0, 1.0)
    return (conf * factor).astype(np.float32)


def view_gains(inputs: Scene, planned: list[Frame], gain: np.ndarray) -> np.ndarray:
    """Each planned view's gain: the mean of ``gain`` (one per :func:`validation_inputs` view) over the
    held-back inputs nearest to it by index (ties: all of them)."""
    at = np.array([inputs.frames[i].index for i in validation_inputs(len(inputs))])
    out = []
    for f in planned:
        d = np.abs(at - f.index)
        out.append(float(np.mean(gain[np.isclose(d, d.min())])))
    return np.array(out)


@dataclass
class _Fits:
    """The validation fits' numbers: PSNR at the held-back inputs without views and per weight."""

    without: np.ndarray
    by_weight: dict[float, np.ndarray]
    reference: np.ndarray  # (T, h, w, 3) renders of the fit without views at the planned poses


def _validation_views(
    inputs: Scene, small: Scene, planned: list[Frame], synth: SynthFn, base: Renderer, ref: np.ndarray, cfg
) -> tuple[ValidationViews, FixerFit | None]:
    """The planned views synthesized without the held-back inputs, at ``small``'s size, fixed with ``ref`` (the
    render there of ``base``, the fit without the held-back inputs) when the fixer beats both on those inputs."""
    cam = small.cameras[planned[0].camera_id]
    size = (cam.width, cam.height)
    raw = validation_views(inputs, planned, synth)
    conf = None if raw.confidence is None else resize_images(raw.confidence, size)
    vv = ValidationViews(resize_images(raw.images, size), conf, raw.sources)
    if not cfg.fixer:
        return vv, None
    fix = held_back_fixer(inputs, small, base, synth, FIXER_STEPS, cfg.check_seed)
    if fix.fixer is None:
        return vv, fix
    return replace(vv, images=fixed(fix.fixer, vv.images, ref, vv.confidence)), fix


def _validation_fits(
    small: Scene, planned: list[Frame], views: ValidationViews, base: Renderer, ref: np.ndarray, fit, cfg
) -> tuple[_Fits, ValidationViews]:
    """Lower the validation views' confidence against ``ref`` (the render of the fit without views, ``base``),
    fit with them per weight."""
    views = replace(views, confidence=informative_confidence(views.images, views.confidence, ref, cfg))
    return _Fits(held_back_psnr(small, base), weight_scores(small, planned, views, cfg.check_weights, fit), ref), views


@dataclass
class _Decision:
    keep: np.ndarray  # (T,) bool
    weight: float
    best: float  # mean held-back PSNR of the chosen set
    kept_psnr: float | None
    gains: np.ndarray  # (T,) dB per view


def _decide(small: Scene, planned: list[Frame], views: ValidationViews, fits: _Fits, fit, cfg) -> _Decision:
    """The weight with the best held-back PSNR; the views that gain there, refitted alone when that is a
    proper subset, kept when they beat every view together."""
    means = {w: float(v.mean()) for w, v in fits.by_weight.items()}
    w = max(means, key=lambda k: means[k])
    gains = view_gains(small, planned, fits.by_weight[w] - fits.without)
    keep = gains > cfg.min_gain
    if not 0 < keep.sum() < len(planned):
        return _Decision(np.ones(len(planned), bool), w, means[w], None, gains)
    idx = np.flatnonzero(keep)
    sub = ValidationViews(views.images[idx], None if views.confidence is None else views.confidence[idx], views.sources)
    kept_psnr = float(weight_scores(small, [planned[i] for i in idx], sub, [w], fit)[w].mean())
    if kept_psnr < means[w]:
        return _Decision(np.ones(len(planned), bool), w, means[w], kept_psnr, gains)
    return _Decision(keep, w, kept_psnr, kept_psnr, gains)


def self_check(inputs: Scene, planned: list[Frame], synth: SynthFn, final, cfg: SelfCheckConfig, plan: str) -> Checked:
    """Keep the planned views that pay (see the module docstring).

    inputs: the N input photos (any size, in path order, with sparse points for 3DGS); planned: the views'
    frames; synth: the network ``(scene, targets) -> Synthesized``; final: what it made from all inputs (the
    views that would be written: a Synthesized or (T, H, W, 3) images); plan: how the poses were planned.
    Returns the kept views with their exported confidence and the decision, logged in one line."""
    fit = check_fit(cfg)
    small = at_check_size(inputs, cfg)
    base = fit(validation_split(small)[1])
    ok = checkable(small, planned)
    sub = [planned[i] for i in np.flatnonzero(ok)]
    ref = renders(base, small, planned)
    if not sub:
        return _nothing_checkable(small, planned, final, base, cfg, plan)
    vv, fix = _validation_views(inputs, small, sub, synth, base, ref[ok], cfg)
    fits, vv = _validation_fits(small, sub, vv, base, ref[ok], fit, cfg)
    d = _decide(small, sub, vv, fits, fit, cfg)
    without = float(fits.without.mean())
    paid = d.best - without > cfg.min_gain
    keep, gains = np.zeros(len(planned), bool), np.full(len(planned), np.nan)
    keep[ok], gains[ok] = d.keep & paid, d.gains
    record = SelfCheck(
        recon=cfg.recon,
        plan=plan,
        validation=_held_back_names(small),
        psnr_without=without,
        psnr_by_weight=tuple((w, float(v.mean())) for w, v in fits.by_weight.items()),
        psnr_kept=d.kept_psnr,
        weight=d.weight if paid else None,
        views=_view_checks(planned, gains, keep),
        reason=_reason(cfg.recon, int(keep.sum()), len(planned), d, without, int((~ok).sum())),
        fixer=None if fix is None else fix.record,
    )
    (log.info if paid else log.warning)("self-check: %s", record.reason)
    images, conf = images_and_confidence(final)
    idx = np.flatnonzero(keep)
    fixer = None if fix is None else fix.fixer
    reference = fit(small) if fixer is not None and len(idx) else None
    if fixer is not None and reference is not None:
        images = fixed(fixer, images, renders(reference, small, planned), conf)
    exported = _exported(images, conf, ref, d.weight, cfg)
    return Checked([planned[i] for i in idx], images[idx], exported[idx], record, fixer, reference)


def _held_back_names(small: Scene) -> tuple[str, ...]:
    return tuple(small.frames[i].name for i in validation_inputs(len(small)))


def _view_checks(planned: list[Frame], gains: np.ndarray, keep: np.ndarray) -> tuple[ViewCheck, ...]:
    """One record per planned view; gain None where it could not be checked (NaN in ``gains``)."""
    return tuple(
        ViewCheck(f.name, float(f.index), None if np.isnan(g) else float(g), bool(k))
        for f, g, k in zip(planned, gains, keep)
    )


def _nothing_checkable(small: Scene, planned: list[Frame], final, base: Renderer, cfg, plan: str) -> Checked:
    """The decision when no planned view can be checked (:func:`checkable`): none is written."""
    without = float(held_back_psnr(small, base).mean())
    reason = (
        f"none of the {len(planned)} planned views lies where the held-back input photos can measure it (each "
        f"is between the neighbours of one): the capture is written without synthesized views"
    )
    log.warning("self-check: %s", reason)
    gains = np.full(len(planned), np.nan)
    record = SelfCheck(
        cfg.recon,
        plan,
        _held_back_names(small),
        without,
        (),
        None,
        None,
        _view_checks(planned, gains, gains > 0),
        reason,
    )
    images, _ = images_and_confidence(final)
    return Checked([], images[:0], np.zeros(images[:0].shape[:3], np.float32), record)


def checked_views(
    inputs: Scene,
    paper: list[Frame],
    plan: PlanConfig,
    synth: SynthFn,
    cfg: SelfCheckConfig,
    sources: Scene | None = None,
) -> tuple[list[Frame], Checked, Synthesized | np.ndarray]:
    """What ``densify --recon cfg.recon`` writes: (the planned frames, the kept views, the network's answer
    for every planned frame). The poses are ``paper`` (the paper's plan) or, with ``cfg.plan_mode`` weak,
    :func:`weakest_plan`'s; the views are synthesized from ``sources`` (default: ``inputs``) and kept by
    :func:`self_check` on ``inputs``."""
    targets = weakest_plan(at_check_size(inputs, cfg), plan, check_fit(cfg)) if cfg.plan_mode == "weak" else paper
    final = synth(inputs if sources is None else sources, targets)
    return targets, self_check(inputs, targets, synth, final, cfg, cfg.plan_mode), final


def _exported(images: np.ndarray, conf: np.ndarray | None, reference: np.ndarray, weight: float, cfg) -> np.ndarray:
    """The written views' confidence: the network's, lowered where the view agrees with the render of the fit
    without views (at that fit's size, then scaled up), times the synthetic-frame weight."""
    h, w = reference.shape[1:3]
    factor = informative_confidence(resize_images(images, (w, h)), None, reference, cfg)
    factor = np.clip(resize_images(factor, (images.shape[2], images.shape[1])), 0.0, 1.0)
    base = np.ones(images.shape[:3], np.float32) if conf is None else np.asarray(conf, np.float32)
    return np.clip(base * factor * weight, 0.0, 1.0).astype(np.float32)


def _reason(recon: str, kept: int, planned: int, d: _Decision, without: float, unchecked: int) -> str:
    aside = f" ({unchecked} planned between the neighbours of a held-back photo could not be checked)" * (unchecked > 0)
    if kept == 0:
        return (
            f"no synthesized view improves the {recon} fit on the held-back input photos (best {d.best:.2f} dB, "
            f"{without:.2f} dB without views){aside}: the capture is written without synthesized views"
        )
    return (
        f"kept {kept} of {planned} synthesized views at weight {d.weight:g}: the {recon} fit renders the "
        f"held-back input photos at {d.best:.2f} dB with them, {without:.2f} dB without{aside}"
    )
