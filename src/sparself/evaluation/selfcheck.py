"""The densify self-check: synthesized views are kept only where they make the chosen reconstruction better
at held-back *input* photos, so a densified capture is never worse than the N photos alone there (at other
poses it can be: the check measures with the error of its folds, whose gaps are twice the final fit's).

* **Look before synthesizing** (:func:`weakest_plan`): two fits on complementary halves of the inputs (every
  other view) are rendered at candidate poses (:func:`sparself.synthesis.plan.candidate_poses`); the gaps and
  ends where they disagree most are where the reconstruction is weakest, and there views are planned, at
  a gap's midpoint (:func:`~sparself.synthesis.plan.pick_poses`: inside a gap the halves' disagreement
  follows how far a pose is from each half's inputs, not the final fit's weakness).
* **Keep only what pays** (:func:`self_check`): in each fold of inputs held back together
  (:mod:`sparself.evaluation.folds`), the fold's views are synthesized again without those photos, and the
  reconstructor is fitted on the rest without and with them at each synthetic-frame weight. A view's gain is
  the PSNR change at its fold's held-back inputs nearest to it, and a fold is scored only at the held-back
  inputs nearest one of its views (:func:`~sparself.evaluation.folds.measuring_photos`: views past the first
  input, judged by the fold holding both ends back, do not answer for the last photo, which none of them is
  nearest to); views that gain are kept (refitted alone to confirm), and where nothing beats the fit without
  views, none is written. By default (``gain_gap`` "own") a
  view is measured inside its own gap, by the fold that holds one of its two neighbouring photos back (two
  folds holding back the odd positions in turn reach every gap): there it acts, though in a hole twice as
  wide as any the final fit, which has that photo, ever has. With "other" it is measured only by a fold that
  holds back neither neighbour, outside its gap (folds of every ``VALIDATION_EVERY``-th interior input, from
  the third and from the fifth, so that together they measure every gap); measured on llff_bird, a view does
  little there and that rule kept almost none of the views that help. Views past the end inputs are judged
  by a third fold that holds both ends back, through stand-ins: the same extrapolations made one input
  further in. A view no fold can measure is neither planned nor kept. The kept views must gain more than their
  spread over the held-back photos and, with ``seed_noise``, more than a second seed alone moves the fits
  without views there (:func:`seed_change`; on a sparse capture that can be a dB or more). With
  ``max_photo_loss`` a fold's views are dropped when, with them, any of its held-back photos (scored or not)
  loses more than that; the spread rule judges what this limit and the gap trend leave (:func:`_gated`).
  Independent fits run side by side (:mod:`sparself.recon.pool`).
* **The gap's width** (``gap_trend``, off by default): a view's gain measured in a gap twice as wide as the
  final fit's is optimistic where the reconstruction renders well. A further fold holds back neighbouring
  pairs of inputs (:func:`~sparself.evaluation.folds.trend_fold`), leaving gaps three wide; the interior
  views' mean gain in gaps two and three wide is extrapolated to one (linear in the log of the width), and
  when that is not above ``min_gain`` no view between the inputs is kept (those past the ends keep their fold's
  decision: there the final fit lacks the photos as the check's does).
* **Against content-free fills** (``fill_control``; by default for the MPI): a frame at a new pose can gain
  whatever it shows, as one more reference in the MPI's blend or as cover for a held-back end photo that the
  other inputs leave black. Each fold that keeps views is fitted again with flat fills of their mean colours
  and with two draws of uniform noise in their place, and a view stays only where its nearest scored photos
  render better with it than with every fill (:func:`_fill_controlled`).
* **Confirm on other photos** (``confirm``; by default for the 3DGS and the NeRF): the views are kept on the
  folds' held-back photos, so their gain there is chosen as much as measured. Two more folds hold back the
  interior photos no fold held back (:func:`~sparself.evaluation.folds.confirm_folds`); the kept views,
  synthesized again without those photos, are fitted beside the rest, and none is kept when there they gain no
  more than their spread over those photos (the folds' rule) or one photo loses more than ``max_photo_loss``: a
  view that spoils the fit far from the photos it was judged on. With ``confirm_prune`` the views in the gap of
  a photo that loses more than that are dropped first and the rest tested once more on the same photos (a
  second choice made on them, so it is measured on the held-out frames before it is trusted).
* **Fix before checking** (:mod:`sparself.evaluation.fixing`): a small network trained on every fold's
  held-back inputs merges each view with the render of the fit without it, pixel by pixel; the merged views
  replace the network's when they beat both the views and the render on those photos (each scored by a
  fixer that did not train on it). A fold's views are fixed by a fixer trained on the other fold's photos.
* **Render -> fix -> refit** (``fix_rounds``, one round by default): after the first round each fold is fitted
  with its views; a new fixer, trained on the held-back photos' network views and those fits' renders there,
  merges the network's views with those fits' renders at the views' poses (:func:`_refixed`). A round is kept
  while the folds fitted with its views render their scored photos better by more than the spread over them;
  the confirmation's views and the written ones then go through the kept rounds too (:func:`_replayed`).
* **Per pixel** (:func:`informative_confidence`): where a view agrees with the render of the fit without it
  within ``agree_within``, it adds nothing that reconstruction does not already make, so its confidence is
  lowered there (written as the exported mask, so gsplat/nerfstudio users get the same effect). With
  ``pixel_weights`` choose (the 3DGS's default) every fold also fits its views with every pixel alike, and the
  way that renders the held-back photos better decides (:func:`_pixel_weighted`), the other when it keeps no
  view: on llff_bird at 9 inputs the lowered confidence cost the 3DGS 0.5 dB.

The self-check's fits run at ``check_size`` pixels with ``check_steps`` optimisation steps: it compares fits
with each other, so they need not be the user's final fit, only alike.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Callable, Literal

import numpy as np
import torch

from sparself.capture.images import resize_images
from sparself.capture.io.dense import Confirmation, FillControl, FixRound, GapTrend, SelfCheck, ViewCheck
from sparself.capture.scene import Frame, Scene, preloaded
from sparself.core.content import same_content
from sparself.core.errors import ConfigError
from sparself.core.metrics import clear_gain, gain, standard_error
from sparself.core.options import check_choices, option
from sparself.evaluation.config import Gap, KeepRule, PixelWeights
from sparself.evaluation.fixing import FixerFit, FixerPairs, fixed, fixer_pairs, refit_pairs, validated_fixer
from sparself.evaluation.folds import (
    beyond,
    check_folds,
    checkable,
    confirm_folds,
    measuring_fold,
    measuring_photos,
    nearest_held,
    one_wide_gain,
    stand_ins,
    trend_fold,
    view_gains,
)
from sparself.evaluation.instruments import SynthFn, images_and_confidence, renders, with_images
from sparself.evaluation.reach import choose_reach, reach_to_choose
from sparself.evaluation.results import ReachChoice
from sparself.evaluation.weighting import (
    ValidationViews,
    held_back_psnr,
    validation_inputs,
    validation_split,
    weight_scenes,
    weighted_scene,
)
from sparself.model.fixer import Fixer
from sparself.recon import Renderer, backend
from sparself.recon.pool import FitPool, Fitter, side_by_side
from sparself.synthesis.plan import PlanConfig, candidate_poses, pick_poses, weakness_decides
from sparself.synthesis.synthesize import Synthesized

log = logging.getLogger(__name__)

FIXER_STEPS = 300  # optimisation steps of each fixer fit (a few seconds at the check size)
PARALLEL_STEPS = 100  # self-check fits shorter than this run one after the other (a worker starts in seconds)
BLUR = 5  # px: the view-minus-render difference is averaged over this window before it is compared


@dataclass
class SelfCheckConfig:
    """How ``densify`` checks its views against a reconstruction (each field's help is its documentation)."""

    recon: Literal["3dgs", "nerf", "mpi", "none"] = option(
        "3dgs",
        "reconstruction the views must improve: plan where it is weak, keep only views that raise its PSNR on "
        "held-back input photos (none: the paper's plan, every view kept, no fit)",
    )
    plan_mode: Literal["auto", "weak", "paper"] = option(
        "auto",
        "where views go: where fits on complementary halves of the inputs disagree most (weak), or the "
        "paper's midpoints and extrapolations (paper; always with --recon none); auto: paper for the NeRF "
        "(measured: +0.85 dB against +0.02 with weak at 25 llff_bird inputs, +0.97 against +0.40 on samples/bird), "
        "weak for the 3DGS and the MPI",
        flag="--plan",
    )
    check_size: int = option(
        64, "long side in px of the self-check's fits (a CPU 3DGS step costs about 4x more at twice the side)"
    )
    check_steps: int | None = option(
        300, "optimisation steps of each self-check fit (auto: the reconstructor's own, slower)"
    )
    check_weights: tuple[float, ...] | None = option(
        None,
        "synthetic-frame loss weights tried (one fit each on the inputs minus the held-back ones; auto: 1 for the "
        "3DGS, which chose it over 0.5 on 12 of 15 capture seeds, and 0.5,1 for the others)",
    )
    min_gain: float = option(
        0.0, "dB a view must add at its held-back inputs to be kept (and the kept views together: more than its spread)"
    )
    agree_within: float = option(
        0.03,
        "mean absolute difference (0..1) within which a synthesized pixel agrees with the render of the fit "
        "without it; its confidence is lowered there (0: never)",
    )
    agree_weight: float = option(0.3, "the factor the confidence of such agreeing pixels is multiplied by")
    pixel_weights: PixelWeights = option(
        "auto",
        "per-pixel loss weights of the views in the check's fits and in the written masks: the network's "
        "confidence, lowered where a view agrees with the render (confidence), or the synthetic-frame weight "
        "on every pixel (uniform: what a trainer that ignores masks, such as gsplat's, fits); choose: the folds "
        "fit the views both ways and use the one that renders their held-back photos better, the other when it "
        "keeps no view; auto: choose for the 3DGS (measured: +2.20 dB at 9 llff_bird inputs against +1.69 with "
        "confidence, at least as much on four other captures), confidence for the others",
    )
    keep: KeepRule = option(
        "each",
        "which views a fold keeps: those that gain on their own, refitted alone when they are not all of them "
        "(each), or every view of the fold when together they gain and none otherwise (together: one decision "
        "per fold, less chosen on the held-back photos' noise)",
    )
    gap_trend: bool = option(
        False,
        "also fit a fold holding back neighbouring pairs of inputs (gaps three inputs wide, where the own-gap "
        "folds leave two), extrapolate the views' gain between the inputs from those widths to the final "
        "fit's (linear in the log of the width), and keep no view between the inputs when that is not above "
        "min_gain (with gain_gap own)",
    )
    max_photo_loss: float | None = option(
        1.0,
        "dB: drop a fold's views when, fitted with those it keeps, any of its held-back photos loses more than this, "
        "near a view or not (a view can spoil a 3DGS fit far from its own gap; measured, this kept the 3DGS at or "
        "above N on every seed where nothing else did); inf: never",
    )
    ends_context: bool | None = option(
        None,
        "the fold that judges the views past the ends fits them beside the views between the inputs "
        "(synthesized without the end photos, at the largest check weight), as the final fit has them; no: "
        "beside the photos alone; auto: yes for the 3DGS, no for the MPI (measured: it put a samples/bird seed "
        "below N) and the NeRF (measured: it kept less at 9 llff_bird inputs, +1.00 against +1.16 dB)",
    )
    fill_control: bool | None = option(
        None,
        "each fold also fits content-free fills in place of its kept views (flat fills of their mean colours, and "
        "two draws of uniform noise; the same poses and weights), and keeps a view only where it beats every fill "
        "at its held-back photos by more than min_gain: a frame at a new pose can gain by being there (another "
        "reference for the MPI's blend, cover for a photo past the ends), whatever it shows (auto: for the MPI; "
        "measured: see docs/results.md)",
    )
    check_seed: int = option(0, "seed of the self-check's fits")
    far_reach: tuple[float, ...] = option(
        (1.0, 5.0),
        "CPU 3DGS: how many times further than the sparse points' far depth the check's fits start their random "
        "Gaussians, on captures whose depth bounds come from their points; several, comma-separated: the one whose "
        "fit without the held-back inputs renders them best (the first on ties); one: that reach (1: to the "
        "points' depth); see docs/results.md",
        flag="--splat-far-reach",
    )
    check_workers: int | None = option(
        None,
        "processes the self-check's fits run in at once (auto: one per core, at most 4, for the CPU 3DGS, "
        "which fits on one core; 1 otherwise)",
    )
    fixer: bool = option(
        True,
        "merge each view with the render of the fit without it, pixel by pixel, by a small network trained on "
        "the held-back input photos (used only when it beats both the views and the render there)",
    )
    fix_rounds: int = option(
        1,
        "rounds of render -> fix -> refit (with the fixer): after a round, each fold is fitted with that round's "
        "views, a new fixer is trained on the held-back photos with those fits' renders and merges the network's "
        "views with them at the views' poses; a round is kept while it raises the folds' held-back photos by more "
        "than its spread over them (one more fit per fold and round, and one per confirmation fold and for the "
        "written views)",
    )
    gain_gap: Gap = option(
        "own",
        "where a view's gain is measured: inside its own gap (own: the fold holds a neighbour of the view back, "
        "so the view fills a gap twice as wide as in the final fit) or at the held-back photos outside it "
        "(other: no fold widens that gap; on llff_bird it kept almost no view that helps, measured)",
    )
    confirm: bool | None = option(
        None,
        "test the kept views together on the interior input photos no fold held back (two more folds, the "
        "views synthesized again without their photos), and keep none when there the fit with them gains no "
        "more than its spread over those photos on the mean (as the folds' rule) or any photo loses more than "
        "max_photo_loss: the views were chosen on the other photos; "
        "auto: for the 3DGS (measured: it kept llff_bird 25 at N where two seeds lost 1.2 dB, and 9 inputs at "
        "+1.69 dB as without it) and the NeRF (it refused the dinoSparseRing seed that lost 0.06 dB and confirmed "
        "every llff_bird seed); off for the MPI (it refused the +0.09 dB of 25 llff_bird inputs)",
    )
    confirm_prune: bool | None = option(
        None,
        "when a photo of the confirmation loses more than max_photo_loss, drop the kept views inside its gap "
        "(between its neighbouring inputs) and test the rest once more on the same photos, instead of keeping "
        "none: a view acts mostly in its own gap (auto: for the 3DGS, where it kept views on two of three "
        "dinoSparseRing seeds, +0.30 dB against 0, and 6 of a samples/bird seed's 7, +0.25 dB; not measured with "
        "the NeRF)",
    )
    loss_within_gain: bool = option(
        True,
        "the confirmation also fails when one of its photos loses more than its photos gain on the mean: such "
        "views trade one part of the capture for another, and a gain that small is within what the check's "
        "smaller fits can tell from the final fit's (measured: see docs/results.md)",
    )
    seed_noise: bool = option(
        False,
        "fit each fold without views at a second seed too, and keep views only when their gain at the held-back "
        "photos exceeds what the change of seed alone does there (off by default: on llff_bird at 9 inputs it "
        "rejected a seed whose views gained and kept the one whose views lost)",
    )

    def validate(self) -> None:
        check_choices(self)
        if self.fix_rounds < 1:
            raise ConfigError(f"fix_rounds must be >= 1, got {self.fix_rounds}")
        if not self.far_reach or min(self.far_reach) < 1:
            raise ConfigError(f"far_reach must be one or more reaches >= 1, got {self.far_reach}")
        if self.check_workers is not None and self.check_workers < 1:
            raise ConfigError(f"check_workers must be >= 1, got {self.check_workers}")
        if self.check_size < 8 or (self.check_steps is not None and self.check_steps < 1):
            raise ConfigError(
                f"check_size must be >= 8 and check_steps >= 1, got {self.check_size}, {self.check_steps}"
            )
        if self.check_weights is not None and (not self.check_weights or min(self.check_weights) <= 0):
            raise ConfigError(f"check_weights must be one or more weights > 0, got {self.check_weights}")
        if self.max_photo_loss is not None and self.max_photo_loss < 0:
            raise ConfigError(f"max_photo_loss must be >= 0 dB, got {self.max_photo_loss}")
        if self.gap_trend and self.gain_gap != "own":
            raise ConfigError("gap_trend needs gain_gap own (it extrapolates the gain inside a view's own gap)")
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
    reference: Renderer | None = None  # the fit on all inputs at the check size whose renders the fixer merges in


FitMany = Callable[[list[Scene]], list[Renderer]]  # scenes -> one fitted renderer per scene, in order


def check_settings(cfg: SelfCheckConfig) -> dict:
    kw: dict = {} if cfg.recon == "mpi" else {"seed": cfg.check_seed, "progress": False}
    if cfg.check_steps is not None and cfg.recon != "mpi":
        kw["steps"] = cfg.check_steps
        if backend(cfg.recon) == "splat":
            kw["min_steps_per_view"] = 0  # the CPU path raises steps to 60 per view otherwise
    if cfg.far_reach != (1.0,) and backend(cfg.recon) == "splat":
        kw["far_reach"] = cfg.far_reach[0]  # the others are for :func:`choose_reach`
    return kw


def other_seed(cfg: SelfCheckConfig) -> SelfCheckConfig | None:
    """The check at the second seed its folds are fitted with, without views (None: ``cfg.seed_noise`` is
    off, or the reconstructor takes no seed)."""
    return replace(cfg, check_seed=cfg.check_seed + 1) if cfg.seed_noise and "seed" in check_settings(cfg) else None


def check_fits(cfg: SelfCheckConfig, pool: FitPool | None = None) -> FitMany:
    """fits(scenes) -> renderers for ``cfg.recon`` with the self-check's steps and seed, run by ``pool``
    (default: one after the other in this process)."""
    fitter, pool = Fitter(cfg.recon, check_settings(cfg)), pool or FitPool(1)
    return lambda scenes: fitter.many(scenes, pool)


def remembering(fits: FitMany) -> FitMany:
    """``fits`` that fits a scene of real photos only once, by its frames' names and weights (the halves, the
    folds' bases and the reference recur with every network seed of one capture; the fits are seeded).
    Scenes with synthesized frames are always fitted. Use one per capture and check size."""
    memo: dict[tuple, Renderer] = {}

    def key(sc: Scene) -> tuple | None:
        return None if any(f.synthetic for f in sc.frames) else tuple((f.name, f.weight) for f in sc.frames)

    def run(scenes: list[Scene]) -> list[Renderer]:
        todo = [sc for sc in scenes if key(sc) is None or key(sc) not in memo]
        new = iter(fits(todo))
        out = []
        for sc in scenes:
            k = key(sc)
            r = next(new) if k is None or k not in memo else memo[k]
            if k is not None:
                memo[k] = r
            out.append(r)
        return out

    return run


def reusing(fits: FitMany, done: list[tuple[Scene, Renderer]]) -> FitMany:
    """``fits`` that hands back ``done``'s fit of a scene equal to one asked for (the same frames, images, weights,
    confidence and points: :func:`same_content`; the fits are seeded) and fits only the rest."""

    def run(scenes: list[Scene]) -> list[Renderer]:
        found = [next((r for d, r in done if same_content(sc, d)), None) for sc in scenes]
        new = iter(fits([sc for sc, r in zip(scenes, found) if r is None]))
        return [next(new) if r is None else r for r in found]

    return run


def check_workers(cfg: SelfCheckConfig) -> int:
    """How many fits the self-check runs at once (``cfg.check_workers``; auto: see its help, and 1 for fits
    shorter than PARALLEL_STEPS steps, which take less time than starting a worker)."""
    if cfg.check_workers is not None:
        return cfg.check_workers
    short = cfg.check_steps is not None and cfg.check_steps < PARALLEL_STEPS
    return 1 if short else side_by_side(cfg.recon)


def check_cameras(scene: Scene, cfg: SelfCheckConfig) -> Scene:
    """The scene with its cameras at ``cfg.check_size`` (never enlarged); no image is read."""
    side = max(max(c.width, c.height) for c in scene.cameras.values())
    return scene.resized(cfg.check_size) if side > cfg.check_size else scene


def at_check_size(scene: Scene, cfg: SelfCheckConfig) -> Scene:
    """The scene with images in memory at ``cfg.check_size`` (never enlarged)."""
    return preloaded(check_cameras(scene, cfg))


def weakest_plan(inputs: Scene, plan: PlanConfig, fits: FitMany, gap: Gap) -> list[Frame]:
    """``plan.n_mid`` gaps and ``plan.n_extra`` extrapolations where two fits on complementary halves of
    ``inputs`` (even and odd positions; a scene in path order) disagree most (mean absolute difference of
    their renders over the poses of :func:`sparself.synthesis.plan.candidate_poses` in the gap or past the
    end that are measured by one of the self-check's folds (:func:`measuring_fold`), when there are any),
    placed as :func:`sparself.synthesis.plan.pick_poses` says; without fitting when no disagreement could
    move the picks (:func:`~sparself.synthesis.plan.weakness_decides`)."""
    cands = candidate_poses(inputs, replace(plan, order="capture"))
    ok = measuring_fold(inputs, [c.frame for c in cands], gap) >= 0
    if ok.any():  # else every view is planned unchecked, and the self-check says it keeps none
        cands = [c for c, k in zip(cands, ok) if k]
    if not weakness_decides(cands, plan):  # a view in every gap, the ends visited alike: nothing to rank
        picked = pick_poses(cands, np.zeros(len(cands)), plan)
        log.info("plan: %d views, one in every gap and as many past each end (no fits needed)", len(picked))
        return picked
    frames = [c.frame for c in cands]
    halves = fits([inputs.subset(range(k, len(inputs), 2)) for k in (0, 1)])
    a, b = (renders(r, inputs, frames) for r in halves)
    weak = np.abs(a - b).mean(axis=(1, 2, 3))
    picked = pick_poses(cands, weak, plan)
    log.info(
        "plan: %d views in the gaps and ends where halves of the inputs disagree most (at them %.4f .. %.4f; "
        "candidates %.4f .. %.4f)",
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


@dataclass
class _Context:
    """Planned views a fold fits beside its own in every one of its fits (the fit without its views
    included), synthesized without its held-back photos, at one loss weight."""

    frames: list[Frame]
    views: ValidationViews
    weight: float


def _with_context(scene: Scene, ctx: _Context | None) -> Scene:
    """``scene`` + the context's views at the context's weight (its own frames' weights unchanged)."""
    if ctx is None:
        return scene
    names = {f.name for f in ctx.frames}
    sc = with_images(scene, ctx.frames, ctx.views.images, ctx.views.confidence)
    ours = [replace(f, weight=ctx.weight) if f.synthetic and f.name in names else f for f in sc.frames]
    return replace(sc, frames=ours)


def plan_of(cfg: SelfCheckConfig) -> Literal["weak", "paper"]:
    """Where the views go (``cfg.plan_mode``; auto: the paper's plan for the NeRF and without a check, the weak
    plan for the others)."""
    if cfg.plan_mode != "auto":
        return cfg.plan_mode
    return "paper" if cfg.recon in ("nerf", "none") else "weak"


def weights_of(cfg: SelfCheckConfig) -> tuple[float, ...]:
    """The synthetic-frame weights the folds are fitted at (``cfg.check_weights``; auto: 1 alone for the 3DGS,
    where it won on nearly every capture and seed and a second weight costs a fit per fold, 0.5 and 1 for the
    others)."""
    if cfg.check_weights is not None:
        return cfg.check_weights
    return (1.0,) if cfg.recon == "3dgs" else (0.5, 1.0)


def prune_on(cfg: SelfCheckConfig) -> bool:
    """Whether a failed confirmation drops the views beside its losing photos and tests the rest again
    (``cfg.confirm_prune``; auto: for the 3DGS)."""
    return cfg.confirm_prune if cfg.confirm_prune is not None else cfg.recon == "3dgs"


def confirm_on(cfg: SelfCheckConfig) -> bool:
    """Whether the kept views are confirmed on the photos no fold held back (``cfg.confirm``; auto: for the
    3DGS and the NeRF, where it kept every capture at or above N)."""
    return cfg.confirm if cfg.confirm is not None else cfg.recon in ("3dgs", "nerf")


def pixel_weights_of(cfg: SelfCheckConfig) -> Literal["choose", "confidence", "uniform"]:
    """``cfg.pixel_weights`` with auto resolved (see its help)."""
    if cfg.pixel_weights != "auto":
        return cfg.pixel_weights
    return "choose" if cfg.recon == "3dgs" else "confidence"


def ends_context_on(cfg: SelfCheckConfig) -> bool:
    """Whether the ends fold fits its stand-ins beside the views between the inputs (``cfg.ends_context``;
    auto: for the 3DGS only)."""
    return cfg.ends_context if cfg.ends_context is not None else cfg.recon == "3dgs"


def fill_control_on(cfg: SelfCheckConfig) -> bool:
    """Whether the kept views must beat content-free fills at their poses (``cfg.fill_control``; auto: for the
    MPI)."""
    return cfg.fill_control if cfg.fill_control is not None else cfg.recon == "mpi"


def _ends_context(inputs: Scene, small: Scene, planned: list[Frame], held: list[int], synth, cfg) -> _Context | None:
    """For the fold holding the ends back (``held``): the planned views between the inputs, synthesized from
    the other inputs, with the network's confidence as pixel weights (not lowered where they agree with a
    render: the fit without them is not made), none with uniform pixel weights (None when off, for another
    fold, or when there is none)."""
    inner = [f for f, past in zip(planned, beyond(small, planned)) if not past]
    if not ends_context_on(cfg) or 0 not in held or not inner:
        return None
    _, train = validation_split(inputs, held)
    images, conf = images_and_confidence(synth(train, inner))
    views = _at_check_size(small, inner, images, None if pixel_weights_of(cfg) == "uniform" else conf, train)
    return _Context(inner, views, max(weights_of(cfg)))


def _at_check_size(small: Scene, frames: list[Frame], images, conf, train: Scene) -> ValidationViews:
    """Views synthesized from ``train`` at ``frames`` (and their confidence, or None), resized to the
    check's cameras."""
    cam = small.cameras[frames[0].camera_id]
    size = (cam.width, cam.height)
    resized = None if conf is None else resize_images(conf, size)
    return ValidationViews(resize_images(images, size), resized, [f.name for f in train.frames])


@dataclass
class _Fold:
    """One fold of the self-check: its held-back positions, the fit without them, the planned views it
    measures (positions into the plan) and the frames it fits for them (:func:`stand_ins`), those
    synthesized without the held-back photos (at the check size) with the renders of ``base`` there, and
    the fixer's pairs at the held-back photos (None: no fixer is trained on them)."""

    held: list[int]
    base: Renderer
    views: list[int]
    scored: list[int]  # the held-back positions nearest its views, where it is scored (:func:`measuring_photos`)
    frames: list[Frame]
    synthesized: ValidationViews
    reference: np.ndarray  # (V, h, w, 3)
    pairs: FixerPairs | None
    context: _Context | None = None  # views fitted beside its own in each of its fits (base included)
    raw: ValidationViews | None = None  # the network's views before any fixer (what every round's fixer merges)

    @property
    def at_scored(self) -> list[int]:
        """Where the scored photos are among ``held`` (to take their PSNR from one at every held-back photo)."""
        return [self.held.index(h) for h in self.scored]

    @property
    def past_ends(self) -> bool:
        """Whether this is the fold holding both end photos back (for the views past them)."""
        return 0 in self.held


def _fold(
    inputs: Scene,
    small: Scene,
    planned: list[Frame],
    held: list[int],
    views: list[int],
    synth,
    base,
    pairs: bool,
    context: _Context | None = None,
) -> _Fold:
    """The fold with ``base`` (the fit without ``held``): its views and, with ``pairs``, its held-back photos
    synthesized from the other inputs in one call (the photos become the fixer's pairs)."""
    _, train = validation_split(inputs, held)
    frames = stand_ins(small, [planned[i] for i in views])
    images, conf = images_and_confidence(synth(train, frames + [inputs.frames[i] for i in held if pairs]))
    v = len(frames)
    made = _at_check_size(small, frames, images[:v], None if conf is None else conf[:v], train)
    made_pairs = fixer_pairs(small, held, base, images[v:], None if conf is None else conf[v:]) if pairs else None
    scored = measuring_photos(small, [planned[i] for i in views], held)
    return _Fold(held, base, views, scored, frames, made, renders(base, small, frames), made_pairs, context, made)


def _fixed_folds(folds: list[_Fold], cfg: SelfCheckConfig) -> tuple[list[_Fold], FixerFit | None]:
    """The fixer tested on every fold's pairs, each fold's by a fixer trained on the *other* folds' pairs
    (:func:`validated_fixer`; leave-one-out when there is one fold); where it is used, each fold's views are
    fixed by the fixer that scored it, so that no fold's check is scored on photos its fixer learnt from."""
    pairs = [f.pairs for f in folds if f.pairs is not None]  # every fold's, with the fixer on
    if not cfg.fixer or len(pairs) < len(folds):
        return folds, None
    fix, each = _fold_fixers(pairs, cfg)
    if fix.fixer is None:
        return folds, fix
    return [replace(f, synthesized=_fixed_views(fx, f.synthesized, f.reference)) for f, fx in zip(folds, each)], fix


def _fold_fixers(pairs: list[FixerPairs], cfg: SelfCheckConfig) -> tuple[FixerFit, list[Fixer]]:
    """The fixer validated on every fold's ``pairs`` (:func:`validated_fixer`, each fold's scored by one trained
    on the others; leave-one-out when there is one fold) and the fixer that fixes each fold's views: the one
    that scored it (the one trained on every pair with one fold; none when it is not used)."""
    starts = np.cumsum([0] + [len(p) for p in pairs])
    groups = [list(range(a, b)) for a, b in zip(starts[:-1], starts[1:])] if len(pairs) > 1 else None
    fix = validated_fixer(FixerPairs.cat(pairs), FIXER_STEPS, cfg.check_seed, groups)
    if fix.fixer is None:
        return fix, []
    return fix, [fix.held_out[k] if groups is not None else fix.fixer for k in range(len(pairs))]


def _fixed_views(fixer: Fixer, views: ValidationViews, reference: np.ndarray) -> ValidationViews:
    """``views`` fixed by ``fixer`` with the renders at their poses (``reference``: (V, h, w, 3))."""
    return replace(views, images=fixed(fixer, views.images, reference, views.confidence))


def _lowered(views: ValidationViews, reference: np.ndarray, cfg) -> ValidationViews:
    """``views`` with their confidence lowered where they agree with the renders at their poses
    (``reference``: (V, h, w, 3); :func:`_fitted_confidence`), as every fit of the check uses them."""
    return replace(views, confidence=_fitted_confidence(views.images, views.confidence, reference, cfg))


@dataclass
class _Fixers:
    """The fixers every view goes through: the first round's (None: not used) merges the network's view with
    the render of the fit without it; each later one with the render of that fit refitted with the previous
    round's views at ``weight`` (:func:`_refixed`); ``rounds``: each later round tried."""

    first: Fixer | None
    weight: float
    later: tuple[Fixer, ...] = ()
    rounds: tuple[FixRound, ...] = ()

    @property
    def last(self) -> Fixer | None:
        """The fixer that merges the views last (None: none is used)."""
        return self.later[-1] if self.later else self.first


def _fold_scene(small: Scene, f: _Fold, w: float, cfg) -> Scene:
    """The fold's inputs with its views at weight ``w`` (their confidence lowered as in every fit of the
    check), beside its context."""
    return _kept_scene(small, f, _lowered(f.synthesized, f.reference, cfg), np.ones(len(f.frames), bool), w)


def _refixed(
    small: Scene, folds: list[_Fold], fix: FixerFit | None, fits: FitMany, cfg
) -> tuple[list[_Fold], _Fixers, list[tuple[Scene, Renderer]]]:
    """Later rounds of render -> fix -> refit (``cfg.fix_rounds``): each fold is fitted with its views; a fixer
    is trained on the held-back photos' network views and those fits' renders there (validated as the first
    round's, :func:`_fold_fixers`) and merges each fold's network views with those fits' renders at their
    poses; the folds are fitted again with the merges, and the round is kept when that raises their scored
    photos by more than its spread (:func:`~sparself.core.metrics.clear_gain`); the rounds stop at the first
    that is not. -> (the folds after the last kept round, the fixers, [(scene, fit)] of those folds with their
    views: the scoring after the rounds fits the same scenes and takes these instead, :func:`reusing`)."""
    fixers = _Fixers(None if fix is None else fix.fixer, max(weights_of(cfg)))
    pairs = [f.pairs for f in folds if f.pairs is not None]
    raws = [f.raw for f in folds if f.raw is not None]
    if cfg.fix_rounds < 2 or fix is None or len(pairs) < len(folds) or len(raws) < len(folds):
        return folds, fixers, []
    scenes = [_fold_scene(small, f, fixers.weight, cfg) for f in folds]
    fitted = fits(scenes)
    for k in range(2, cfg.fix_rounds + 1):
        before = np.concatenate([held_back_psnr(small, r, f.scored) for f, r in zip(folds, fitted)])
        fit, each = _fold_fixers([refit_pairs(p, small, f.held, r) for p, f, r in zip(pairs, folds, fitted)], cfg)
        if fit.fixer is None:
            fixers = replace(fixers, rounds=fixers.rounds + (FixRound(fit.record, float(before.mean()), None, False),))
            break
        again = [
            replace(f, synthesized=_fixed_views(fx, raw, renders(r, small, f.frames)))
            for f, raw, fx, r in zip(folds, raws, each, fitted)
        ]
        rescenes = [_fold_scene(small, f, fixers.weight, cfg) for f in again]
        refitted = fits(rescenes)
        after = np.concatenate([held_back_psnr(small, r, f.scored) for f, r in zip(again, refitted)])
        kept = clear_gain(gain(after, before), 0.0)
        log.info(
            "self-check: round %d of render -> fix -> refit: the folds' scored photos %.2f -> %.2f dB (%s)",
            k,
            before.mean(),
            after.mean(),
            "kept" if kept else "not kept: not more than its spread over them",
        )
        record = FixRound(fit.record, float(before.mean()), float(after.mean()), kept)
        fixers = replace(fixers, rounds=fixers.rounds + (record,))
        if not kept:
            break
        folds, scenes, fitted = again, rescenes, refitted
        fixers = replace(fixers, later=fixers.later + (fit.fixer,))
    return folds, fixers, list(zip(scenes, fitted))


@dataclass
class _Replay:
    """Views to take through the later rounds (:func:`_replayed`): their frames, the network's images (any
    size) and confidence (None: none), the images after the first round, the positions of ``small`` held back
    (none: every input is fitted) and the fit on the other inputs without views."""

    frames: list[Frame]
    raw: np.ndarray
    confidence: np.ndarray | None
    images: np.ndarray
    held: list[int]
    base: Renderer


def _replayed(
    fixers: _Fixers, small: Scene, jobs: list[_Replay], fits: FitMany, cfg
) -> list[tuple[np.ndarray, Renderer]]:
    """Each job's views through ``fixers.later``, as :func:`_refixed` made its folds': per round, the inputs
    (without the held-back ones) are fitted with the previous round's views (every job's at once), and the
    round's fixer merges the network's views with that fit's renders at their poses.
    Returns per job (the views, the last fit: its base when there is no later round)."""
    out = [(j.images, j.base) for j in jobs]
    for fx in fixers.later:
        refs = fits([_replay_scene(small, j, images, fixers.weight, cfg) for j, (images, _) in zip(jobs, out)])
        out = [(fixed(fx, j.raw, renders(r, small, j.frames), j.confidence), r) for j, r in zip(jobs, refs)]
    return out


def _replay_scene(small: Scene, job: _Replay, images: np.ndarray, w: float, cfg) -> Scene:
    """``small`` without ``job.held`` plus ``images`` at the job's frames and weight ``w``, their confidence
    lowered where they agree with the render of the job's base (as every fit of the check weights views)."""
    train = small.without(job.held) if job.held else small
    views = _at_check_size(small, job.frames, images, job.confidence, train)
    views = _lowered(views, renders(job.base, small, job.frames), cfg)
    return weighted_scene(train, job.frames, views.images, views.confidence, w)


@dataclass
class _Scores:
    """A fold's held-back PSNR (one per held-back photo): without views, with its views per weight, and
    without views at the second seed (None: not fitted)."""

    without: np.ndarray
    by_weight: dict[float, np.ndarray]
    other: np.ndarray | None = None
    worst: dict[float, float] = field(default_factory=dict)  # per weight: the change at the photo that loses most
    held_without: np.ndarray | None = None  # PSNR without views at every held-back photo, scored or not


def _scores(small: Scene, folds: list[_Fold], fits: FitMany, others: list[Renderer] | None, cfg):
    """Each fold's views with their confidence lowered where they agree with its render, and every fold's fits
    with its views at each weight, all fitted at once: [(scores, lowered views)] per fold (``others``: each
    fold's fit without views at the second seed, or None)."""
    return _scores_each(small, folds, fits, others, [cfg])[0][1]


def _scores_each(small: Scene, folds: list[_Fold], fits: FitMany, others: list[Renderer] | None, cfgs: list):
    """:func:`_scores` under each of ``cfgs`` (which differ in their pixel weights), all fitted at once, with
    each one's folds (:func:`_weighted_alike`): [(folds, [(scores, lowered views)] per fold)] per config."""
    variants = [[_weighted_alike(small, f, c) for f in folds] for c in cfgs]
    rebased = [sc for vs in variants for _, sc in vs if sc is not None]
    lowered = [[_lowered(f.synthesized, f.reference, c) for f, _ in vs] for c, vs in zip(cfgs, variants)]
    scenes = rebased + [
        _with_context(sc, f.context)
        for c, vs, views in zip(cfgs, variants, lowered)
        for (f, _), v in zip(vs, views)
        for sc in weight_scenes(small, f.frames, v, weights_of(c), f.held)
    ]
    fitted = fits(scenes)
    bases, with_views = iter(fitted[: len(rebased)]), iter(fitted[len(rebased) :])
    out = []
    for c, vs, views in zip(cfgs, variants, lowered):
        own = [f if sc is None else replace(f, base=next(bases)) for f, sc in vs]
        second: list[Renderer | None] = list(others) if others is not None else [None] * len(own)
        out.append((own, [(_fold_scores(small, f, with_views, o, c), v) for f, o, v in zip(own, second, views)]))
    return out


def _weighted_alike(small: Scene, f: _Fold, cfg) -> tuple[_Fold, Scene | None]:
    """The fold as fitted with ``cfg``'s pixel weights: with uniform ones, its context's views weigh every pixel
    alike too, as they will in the final fit, and its fit without views must be made again on that scene
    (returned; None: the fold is unchanged)."""
    ctx = f.context
    if ctx is None or cfg.pixel_weights != "uniform" or ctx.views.confidence is None:
        return f, None
    ctx = replace(ctx, views=replace(ctx.views, confidence=None))
    return replace(f, context=ctx), _with_context(validation_split(small, f.held)[1], ctx)


def _fold_scores(small: Scene, f: _Fold, fitted, other: Renderer | None, cfg) -> _Scores:
    """One fold's scores, its fits with views taken from ``fitted`` (one per weight, in order)."""
    every, at = held_back_psnr(small, f.base, f.held), f.at_scored
    with_views = {float(w): held_back_psnr(small, next(fitted), f.held) for w in weights_of(cfg)}
    worst = {w: float((p - every).min()) for w, p in with_views.items()}
    second = None if other is None else held_back_psnr(small, other, f.scored)
    return _Scores(every[at], {w: p[at] for w, p in with_views.items()}, second, worst, every)


def _by_weight(scored) -> dict[float, float]:
    """Mean PSNR over every fold's scored photos with its views, per synthetic-frame weight."""
    return {w: float(np.concatenate([s.by_weight[w] for s, _ in scored]).mean()) for w in scored[0][0].by_weight}


def _pixel_weighted(small: Scene, folds: list[_Fold], fits: FitMany, others: list[Renderer] | None, cfg):
    """The folds' scores (:func:`_scores`) per way of weighting the views' pixels, the one that renders the
    held-back photos better first -> ([(the folds as fitted that way, their scores, the check's config with
    it)], [(pixel weights, mean PSNR at its best synthetic-frame weight)] for each tried). Where the pixel
    weights are choose (:func:`pixel_weights_of`) the views are fitted both with their lowered confidence and
    uniformly (the confidence first on a tie); else only the way asked for, and nothing is recorded as tried."""
    if pixel_weights_of(cfg) != "choose":
        one = replace(cfg, pixel_weights=pixel_weights_of(cfg))
        [(own, scored)] = _scores_each(small, folds, fits, others, [one])
        return [(own, scored, one)], ()
    cfgs = [replace(cfg, pixel_weights=m) for m in ("confidence", "uniform")]
    each = _scores_each(small, folds, fits, others, cfgs)
    tried = tuple((c.pixel_weights, max(_by_weight(s).values())) for c, (_, s) in zip(cfgs, each))
    order = [1, 0] if tried[1][1] > tried[0][1] else [0, 1]
    log.info(
        "self-check: the views fitted with their confidence render the held-back photos at %.2f dB, with every "
        "pixel alike at %.2f: %s pixel weights",
        tried[0][1],
        tried[1][1],
        cfgs[order[0]].pixel_weights,
    )
    return [(*each[k], cfgs[k]) for k in order], tried


@dataclass
class _Decision:
    keep: np.ndarray  # (V,) bool, the fold's views
    gains: np.ndarray  # (V,) dB
    chosen: np.ndarray  # held-back PSNR of the kept views (without views when none is kept)
    worst: float | None = None  # dB change, with the kept views, at the fold's held-back photo that loses most


def _decide(small: Scene, planned: list[Frame], folds: list[_Fold], scored, w: float, fits: FitMany, cfg):
    """Per fold, the views that gain at weight ``w`` (every view with ``cfg.keep`` together); where that is a
    proper subset it is refitted alone (all such refits at once) and kept when it beats every view together
    (:func:`_settle`)."""
    gains = [
        view_gains(small, [planned[i] for i in f.views], gain(s.by_weight[w], s.without), f.scored)
        for f, (s, _) in zip(folds, scored)
    ]
    keeps = [np.ones(len(g), bool) if cfg.keep == "together" else g > cfg.min_gain for g in gains]
    partial = [k for k, keep in enumerate(keeps) if 0 < keep.sum() < len(keep)]
    scenes = [_kept_scene(small, folds[k], scored[k][1], keeps[k], w) for k in partial]
    alone = {k: held_back_psnr(small, r, folds[k].held) for k, r in zip(partial, fits(scenes))}
    return [_settle(keeps[k], gains[k], scored[k][0], w, alone.get(k), cfg, folds[k]) for k in range(len(folds))]


def _kept_scene(small: Scene, fold: _Fold, views: ValidationViews, keep, w: float) -> Scene:
    chosen = [fold.frames[i] for i in np.flatnonzero(keep)]
    return _with_context(weight_scenes(small, chosen, _some(views, keep), [w], fold.held)[0], fold.context)


def _settle(
    keep: np.ndarray, gains: np.ndarray, sc: _Scores, w: float, alone: np.ndarray | None, cfg, fold: _Fold
) -> _Decision:
    """The fold's decision: the gaining views when their fit alone (``alone``: PSNR at every held-back photo
    of ``fold``) beats every view together, else every view; none when that does not beat the fit without
    views."""
    chosen, worst = sc.by_weight[w], sc.worst.get(w)
    if alone is not None:
        scored = alone[fold.at_scored]
        if scored.mean() >= chosen.mean():
            chosen = scored
            worst = None if sc.held_without is None else float(gain(alone, sc.held_without).min())
        else:
            keep = np.ones(len(keep), bool)
    if not keep.any() or chosen.mean() - sc.without.mean() <= cfg.min_gain:
        return _Decision(np.zeros(len(keep), bool), gains, sc.without)
    return _Decision(keep, gains, chosen, worst)


def self_check(
    inputs: Scene,
    planned: list[Frame],
    synth: SynthFn,
    final,
    cfg: SelfCheckConfig,
    plan: str,
    fits: FitMany | None = None,
    other: FitMany | None = None,
) -> Checked:
    """Keep the planned views that pay (see the module docstring).

    inputs: the N input photos (any size, in path order, with sparse points for 3DGS); planned: the views'
    frames; synth: the network ``(scene, targets) -> Synthesized``; final: what it made from all inputs (the
    views that would be written: a Synthesized or (T, H, W, 3) images); plan: how the poses were planned;
    fits: how the fits run (default: :func:`check_fits`, one after the other); other: the same at the second
    seed (:func:`other_seed`; None: the views' gain is not compared with what the seed alone does).
    Returns the kept views with their exported confidence and the decision, logged in one line."""
    fits = fits or check_fits(cfg)
    small = at_check_size(inputs, cfg)
    by = measuring_fold(small, planned, cfg.gain_gap)
    held = [h for k, h in enumerate(check_folds(len(small), cfg.gain_gap)) if (by == k).any()]
    if not held:
        return _nothing_checkable(small, planned, final, fits, cfg, plan)
    views = [[int(i) for i in np.flatnonzero(by == k)] for k in sorted(set(by[by >= 0]))]
    wide = _trend_fold(small, planned, cfg)  # fitted beside the folds, scored apart from them
    every = held + [h for h, _ in wide]
    ctx = [_ends_context(inputs, small, planned, h, synth, cfg) for h in held] + [None] * len(wide)
    without = [_with_context(validation_split(small, h)[1], c) for h, c in zip(every, ctx)]
    # the fit on every input, whose renders a fixer merges into the written views, rides with the bases: an odd
    # number of folds leaves a worker free for it
    ref = [small] if cfg.fixer else []
    fitted = fits(without + ref)
    bases, reference = fitted[: len(without)], (fitted[-1] if ref else None)
    others = None if other is None else other(without[: len(held)])
    made = [  # the gap-trend fold's views are not fixed: it needs no fixer pairs
        _fold(inputs, small, planned, h, v, synth, b, cfg.fixer and k < len(held), c)
        for k, (h, v, b, c) in enumerate(zip(every, views + [v for _, v in wide], bases, ctx))
    ]
    folds, fix = _fixed_folds(made[: len(held)], cfg)
    folds, fixers, refits = _refixed(small, folds, fix, fits, cfg)
    ranked, tried = _pixel_weighted(small, folds, reusing(fits, refits), others, cfg)
    tested: list[tuple[_Outcome, SelfCheckConfig]] = []
    for own, scored, c in ranked:  # choosing pixel weights, the other way when the first keeps no view
        tested.append((_outcome(inputs, small, planned, own, made[len(held) :], scored, synth, fits, fixers, c), c))
        if tested[-1][0].keep.any():
            break
    out, cfg = tested[-1] if tested[-1][0].keep.any() else tested[0]
    record = _record(small, planned, plan, out, fix, fixers.rounds, cfg)
    if tried:
        reason = record.reason + _pixel_reason(tried, cfg, tested[0][0] if out is not tested[0][0] else None)
        record = replace(record, psnr_by_pixel_weights=tried, reason=reason)
    (log.info if out.keep.any() else log.warning)("self-check: %s", record.reason)
    return _written(small, planned, final, out.keep, record, out.folds[0], fixers, reference, fits, cfg)


@dataclass
class _Outcome:
    """The check's decision with one way of weighting the views' pixels: the folds as fitted, their scores,
    the mean PSNR per synthetic-frame weight and the one chosen, the gap trend, the folds' decisions, the kept
    planned views and each one's gain (NaN: not checked), the confirmation and how many views it tested, and
    the fill control."""

    folds: list[_Fold]
    scores: list[_Scores]
    weights: dict[float, float]
    w: float
    trend: GapTrend | None
    decided: list[_Decision]
    unclear: bool
    keep: np.ndarray
    gains: np.ndarray
    confirmation: Confirmation | None
    chosen: int
    fill: FillControl | None = None


def _outcome(inputs, small, planned, folds, wide, scored, synth, fits, fixers: _Fixers, cfg) -> _Outcome:
    """The folds' decisions at the best synthetic-frame weight, gated (:func:`_gated`), and their confirmation
    (none kept when it fails; ``wide``: the gap-trend fold, if any)."""
    weights = _by_weight(scored)
    w = max(weights, key=lambda k: weights[k])
    scores = [s for s, _ in scored]
    trend = _gap_trend(small, folds, scores, wide, w, fits, cfg)
    decided = _decide(small, planned, folds, scored, w, fits, cfg)
    decided, fill = _fill_controlled(small, planned, folds, decided, scored, w, fits, cfg)
    decided, unclear = _gated(folds, decided, scores, trend, cfg)
    keep, gains = np.zeros(len(planned), bool), np.full(len(planned), np.nan)
    for f, d in zip(folds, decided):
        keep[f.views], gains[f.views] = d.keep, d.gains
    chosen, confirmation = int(keep.sum()), None
    if confirm_on(cfg):
        confirmation, keep = _confirmation(inputs, small, planned, keep, w, synth, fits, fixers, cfg)
    if confirmation is not None and not confirmation.confirmed:
        decided, keep = [_dropped(d, s) for d, s in zip(decided, scores)], np.zeros(len(planned), bool)
    return _Outcome(folds, scores, weights, w, trend, decided, unclear, keep, gains, confirmation, chosen, fill)


def _confirmation(
    inputs: Scene, small: Scene, planned: list[Frame], keep: np.ndarray, w: float, synth, fits, fixers: _Fixers, cfg
) -> tuple[Confirmation | None, np.ndarray]:
    """The kept views tested together on the photos no fold held back (:func:`confirm_folds`): per fold, they
    are synthesized again without its photos (and fixed as the written ones are), and the inputs without those
    photos are fitted without and with them at weight ``w``, and judged by :func:`_confirmed_by`. When
    :func:`prune_on`, the views inside the gap of a photo that loses more than ``cfg.max_photo_loss`` are dropped
    and the rest tested once more on the same photos (:func:`_pruned`). Returns the confirmation (None when no
    view is kept or there is no such photo) and the views it leaves kept."""
    helds = confirm_folds(len(small), cfg.gain_gap)
    if not helds or not keep.any():
        return None, keep
    frames, fixer = [planned[i] for i in np.flatnonzero(keep)], fixers.first
    bases = fits([validation_split(small, h)[1] for h in helds])
    firsts, jobs = [], []
    for held, base in zip(helds, bases):
        _, train = validation_split(inputs, held)
        images, conf = images_and_confidence(synth(train, frames))
        views, reference = _at_check_size(small, frames, images, conf, train), renders(base, small, frames)
        first = views if fixer is None else _fixed_views(fixer, views, reference)
        firsts.append((first, reference))
        jobs.append(_Replay(frames, views.images, views.confidence, first.images, held, base))
    again = _replayed(fixers, small, jobs, fits, cfg)  # the later rounds, as the folds' views went through them
    made = [_lowered(replace(v, images=im), ref, cfg) for (v, ref), (im, _) in zip(firsts, again)]

    def change(sub: np.ndarray) -> np.ndarray:
        """(photos,) dB change at the confirmation's photos fitted with the views ``sub`` ((V,) bool)."""
        chosen = [f for f, s in zip(frames, sub) if s]
        scenes = [weight_scenes(small, chosen, _some(v, sub), [w], h)[0] for h, v in zip(helds, made)]
        fitted = fits(scenes)
        return np.concatenate(
            [gain(held_back_psnr(small, r, h), held_back_psnr(small, b, h)) for h, b, r in zip(helds, bases, fitted)]
        )

    photos = [p for h in helds for p in h]
    confirmation = _confirmed_by(tuple(small.frames[p].name for p in photos), change(np.ones(len(frames), bool)), cfg)
    log.info(
        "self-check: the %d kept views on %d input photos no fold held back: %s (%s)",
        len(frames),
        len(photos),
        _confirm_change(confirmation.gains),
        "confirmed" if confirmation.confirmed else "not confirmed",
    )
    if not confirmation.confirmed and prune_on(cfg):
        confirmation = _pruned(small, frames, photos, confirmation, change, cfg)
    left = keep.copy()
    left[np.flatnonzero(keep)[[f.name in confirmation.dropped for f in frames]]] = False
    return confirmation, left


def _confirmed_by(photos: tuple[str, ...], gains: np.ndarray, cfg, **more) -> Confirmation:
    """The confirmation of views whose fits change ``photos`` by ``gains`` dB: a clear gain over them, as the
    folds' spread rule asks of the views it keeps (:func:`~sparself.core.metrics.clear_gain`: the mean above its
    standard error and ``cfg.min_gain``; one photo, which has no spread: not under ``cfg.min_gain``), no photo
    losing more than ``cfg.max_photo_loss`` and, with ``cfg.loss_within_gain``, none losing more than the
    photos gain on the mean."""
    safe = cfg.max_photo_loss is None or gains.min() >= -cfg.max_photo_loss
    safe = safe and not (cfg.loss_within_gain and _loss_beyond_gain(gains))
    clear = clear_gain(gains, cfg.min_gain) if gains.size > 1 else bool(gains.mean() >= cfg.min_gain)
    return Confirmation(photos, tuple(float(g) for g in gains), bool(clear and safe), **more)


def _pruned(small: Scene, frames: list[Frame], photos: list[int], first: Confirmation, change, cfg) -> Confirmation:
    """The confirmation again without the views inside the gap of each photo that lost more than
    ``cfg.max_photo_loss`` (between its neighbouring inputs; ``change``: the photos' dB change fitted with a
    subset of ``frames``), or ``first`` when that drops none or all of them: a view acts mostly in its own gap,
    and there a photo that loses says the view disagrees with it."""
    limit = -np.inf if cfg.max_photo_loss is None else -cfg.max_photo_loss
    lost = [p for p, g in zip(photos, first.gains) if g < limit]
    near = checkable(small, frames, "own", lost) if lost else np.zeros(len(frames), bool)
    if not near.any() or near.all():
        return first
    gains = change(~near)
    dropped = tuple(f.name for f, n in zip(frames, near) if n)
    again = _confirmed_by(first.photos, gains, cfg, dropped=dropped, gains_before=first.gains)
    log.info(
        "self-check: the %d kept views without the %d beside the photos that lose most, on the same photos: %s (%s)",
        len(frames) - len(dropped),
        len(dropped),
        _confirm_change(again.gains),
        "confirmed" if again.confirmed else "not confirmed",
    )
    return again


def _some(views: ValidationViews, sub: np.ndarray) -> ValidationViews:
    """``views`` at the positions ``sub`` ((V,) bool) only."""
    conf = None if views.confidence is None else views.confidence[sub]
    return replace(views, images=views.images[sub], confidence=conf)


def _confirm_reason(c: Confirmation, chosen: int, recon: str, reason: str) -> str:
    """The decision's reason with the confirmation (``chosen``: the views it tested; ``reason``: the check's)."""
    measured = f"on {len(c.gains)} input photos no fold held back ({_confirm_change(c.gains)})"
    if c.dropped:
        first = _confirm_change(c.gains_before)
        measured += (
            f" after dropping {len(c.dropped)} of the {chosen} views (those beside a photo that lost more than the "
            f"limit with all of them: {first})"
        )
    if c.confirmed:
        return f"{reason}; confirmed {measured}"
    return (
        f"the {chosen} views that improve the {recon} fit on the held-back input photos are not confirmed "
        f"{measured}: the capture is written without synthesized views"
    )


def _confirm_change(gains) -> str:
    """A confirmation's changes at its photos (dB), in words, with the standard error that :func:`_confirmed_by`
    compares their mean with, and whether the worst photo loses more than the mean gains."""
    g = np.asarray(gains, np.float64)
    spread = f" (standard error {standard_error(g):.2f})" if g.size > 1 else ""
    trade = ", a loss larger than the mean gain" if g.mean() > 0 and _loss_beyond_gain(g) else ""
    return f"{g.mean():+.2f} dB on the mean{spread}, worst {g.min():+.2f}{trade}"


def _loss_beyond_gain(gains: np.ndarray) -> bool:
    """Whether the worst of the photos' changes ``gains`` (dB) loses more than they gain on the mean."""
    return bool(gains.min() < -gains.mean())


def _fill_controlled(
    small: Scene, planned: list[Frame], folds: list[_Fold], decided: list[_Decision], scored, w: float, fits, cfg
) -> tuple[list[_Decision], FillControl | None]:
    """The decisions with each kept view dropped where its fold, fitted with content-free fills in place of its
    kept views (the same poses, weight and pixel weights), renders the view's nearest scored photos about as
    well: there a view gains by what any frame at its pose adds (a reference for the MPI's blend, cover for a
    photo past the ends), not by what it shows. Three fills are fitted: flat fills of the views' mean colours
    and two draws of uniform noise (seeded by ``cfg.check_seed``), and at each photo the views must beat every
    fill by more than ``cfg.min_gain``. A fill's pattern alone moves a fit by up to a few tenths of a dB at a
    photo, so views of noise still pass at some photos; more draws would refuse more of them, at the cost of
    more fits. -> (decisions, the control; None: off, or no view kept)."""
    ks = [k for k, d in enumerate(decided) if d.keep.any()]
    if not fill_control_on(cfg) or not ks:
        return decided, None
    rng = np.random.default_rng(cfg.check_seed)
    makers = (_flat, lambda v: _noise(v, rng), lambda v: _noise(v, rng))
    fitted = iter(
        fits([_kept_scene(small, folds[k], fill(scored[k][1]), decided[k].keep, w) for fill in makers for k in ks])
    )
    by_fill = [[held_back_psnr(small, next(fitted), folds[k].scored) for k in ks] for _ in makers]
    out, photos, dropped, views, flat, noise = list(decided), [], [], [], [], []
    for j, k in enumerate(ks):
        f, d, s = folds[k], decided[k], scored[k][0]
        fl, na, nb = (p[j] for p in by_fill)
        beats = d.chosen - np.maximum(fl, np.maximum(na, nb)) > cfg.min_gain  # (scored photos,) where content pays
        keep = d.keep.copy()
        for v in np.flatnonzero(keep):
            keep[v] = bool(beats[nearest_held(small, f.scored, planned[f.views[v]])].all())
        dropped += [planned[f.views[v]].name for v in np.flatnonzero(d.keep & ~keep)]
        photos += [small.frames[p].name for p in f.scored]
        views += [float(x) for x in d.chosen]
        flat += [float(x) for x in fl]
        noise += [(float(x), float(y)) for x, y in zip(na, nb)]
        # a photo whose nearest views all went renders as without views
        out[k] = replace(d, keep=keep, chosen=np.where(beats, d.chosen, s.without)) if keep.any() else _dropped(d, s)
    control = FillControl(tuple(photos), tuple(views), tuple(flat), tuple(noise), tuple(dropped))
    log.info("self-check: %s", _fill_reason(control).removeprefix("; "))
    return out, control


def _flat(views: ValidationViews) -> ValidationViews:
    """``views`` with each image replaced by its mean colour everywhere (pixel weights unchanged)."""
    means = views.images.mean(axis=(1, 2), keepdims=True)
    return replace(views, images=np.broadcast_to(means, views.images.shape).astype(np.float32))


def _noise(views: ValidationViews, rng: np.random.Generator) -> ValidationViews:
    """``views`` with each image replaced by uniform noise in [0, 1] (pixel weights unchanged)."""
    return replace(views, images=rng.random(views.images.shape, dtype=np.float32))


def _fill_reason(c: FillControl) -> str:
    """The fill control in words."""
    each = ", ".join(
        f"{p} {a:.2f} dB against {b:.2f} / {n[0]:.2f} / {n[1]:.2f}"
        for p, a, b, n in zip(c.photos, c.psnr_views, c.psnr_flat, c.psnr_noise)
    )
    said = f"; {len(c.dropped)} dropped ({', '.join(c.dropped)})" if c.dropped else ""
    return f"; the kept views against flat and two noise fills at their poses, at the held-back photos: {each}{said}"


def _gated(
    folds: list[_Fold], decided: list[_Decision], scores: list[_Scores], trend: GapTrend | None, cfg
) -> tuple[list[_Decision], bool]:
    """The folds' decisions after the gap trend (no interior view when it does not pay), the photo-loss limit
    (:func:`_spared`) and, last, the spread rule (:func:`_confirmed`) on what the first two leave: a fold
    dropped by a gate must not lend its gain to the views of another."""
    if trend is not None and not trend.interior_kept:
        decided = [d if f.past_ends else _dropped(d, s) for f, d, s in zip(folds, decided, scores)]
    return _confirmed(_spared(folds, decided, scores, cfg), scores, cfg)


def _confirmed(decided: list[_Decision], scores: list[_Scores], cfg) -> tuple[list[_Decision], bool]:
    """The folds' decisions, or none kept anywhere (and True) when the kept views' gains at the held-back
    photos of the folds that keep any are not a clear gain (:func:`~sparself.core.metrics.clear_gain`) or
    do not exceed what the second seed alone changes there (:func:`seed_change`): a gain within its own
    spread over the photos, or within the fit's own noise, is not evidence that the views help."""
    kept = [(d, s) for d, s in zip(decided, scores) if d.keep.any()]
    if not kept:
        return decided, False
    gains = np.concatenate([gain(d.chosen, s.without) for d, s in kept])
    noise = seed_change([s for _, s in kept])
    if clear_gain(gains, cfg.min_gain) and (noise is None or gains.mean() > noise):
        return decided, False
    seed = "" if noise is None else f" or within the change of seed alone ({noise:.2f} dB)"
    log.info(
        "self-check: the kept views' gain at the held-back photos (%+.2f dB) is within its spread there%s: "
        "keeping none",
        gains.mean(),
        seed,
    )
    return [_dropped(d, s) for d, s in zip(decided, scores)], True


def _spared(folds: list[_Fold], decided: list[_Decision], scores: list[_Scores], cfg) -> list[_Decision]:
    """The decisions with every view of a fold dropped where, fitted with the views it keeps, one of its
    held-back photos, scored or not, loses more than ``cfg.max_photo_loss`` dB (unset: unchanged)."""
    if cfg.max_photo_loss is None:
        return decided
    out = []
    for f, d, s in zip(folds, decided, scores):
        if not d.keep.any() or d.worst is None or d.worst >= -cfg.max_photo_loss:
            out.append(d)
            continue
        log.info(
            "self-check: the views of the fold holding back %s are dropped: with them a held-back photo loses "
            "%.2f dB (more than %.2f)",
            ", ".join(str(h) for h in f.held),
            -d.worst,
            cfg.max_photo_loss,
        )
        out.append(_dropped(d, s))
    return out


def _dropped(d: _Decision, s: _Scores) -> _Decision:
    """The fold's decision with none of its views kept (its gains still recorded)."""
    return _Decision(np.zeros(len(d.keep), bool), d.gains, s.without)


def _trend_fold(small: Scene, planned: list[Frame], cfg: SelfCheckConfig) -> list[tuple[list[int], list[int]]]:
    """With ``cfg.gap_trend``, the gap-trend fold (:func:`~sparself.evaluation.folds.trend_fold`) as
    [(held-back positions, the planned views inside its gaps)]; [] when off or none lies there."""
    held = trend_fold(len(small)) if cfg.gap_trend else []
    views = [int(i) for i in np.flatnonzero(checkable(small, planned, "own", held))] if held else []
    return [(held, views)] if views else []


def _gap_trend(small: Scene, folds: list[_Fold], scores: list[_Scores], wide: list[_Fold], w: float, fits, cfg):
    """The interior views' gain at weight ``w`` in gaps two inputs wide (the interior folds' held-back photos)
    and three wide (the gap-trend fold ``wide``, its views the network's, not fixed: no fixer trained
    without its photos), extrapolated to one (:func:`~sparself.evaluation.folds.one_wide_gain`); None when
    either is not measured."""
    two = [gain(s.by_weight[w], s.without) for f, s in zip(folds, scores) if not f.past_ends]
    if not wide or not two:
        return None
    [(three, _)] = _scores(small, wide, fits, None, replace(cfg, check_weights=(w,)))
    g2, g3 = float(np.concatenate(two).mean()), float(gain(three.by_weight[w], three.without).mean())
    g1 = one_wide_gain(g2, g3)
    log.info(
        "self-check: the views between the inputs gain %+.2f dB in gaps two inputs wide, %+.2f in gaps three "
        "wide: %+.2f extrapolated to the final fit's gaps%s",
        g2,
        g3,
        g1,
        "" if g1 > cfg.min_gain else " (none of them is kept)",
    )
    return GapTrend(g2, g3, g1, g1 > cfg.min_gain)


def seed_change(scores: list[_Scores]) -> float | None:
    """|mean PSNR change| at the folds' held-back photos from the fits without views at the check's seed to
    those at the second seed: how far the seed alone moves a fit there (None: no second seed fitted)."""
    if not scores or any(s.other is None for s in scores):
        return None
    return abs(float(np.concatenate([gain(s.other, s.without) for s in scores if s.other is not None]).mean()))


def _record(
    small: Scene,
    planned: list[Frame],
    plan: str,
    out: _Outcome,
    fix: FixerFit | None,
    rounds: tuple[FixRound, ...],
    cfg,
) -> SelfCheck:
    """The decision as written to ``sparself.json``: PSNR means over every fold's held-back photos, the
    reason with the gap trend and the confirmation."""
    without = float(np.concatenate([s.without for s in out.scores]).mean())
    seconds = [s.other for s in out.scores if s.other is not None]
    other = float(np.concatenate(seconds).mean()) if seconds and len(seconds) == len(out.scores) else None
    best = float(np.concatenate([d.chosen for d in out.decided]).mean())
    unchecked, kept = int(np.isnan(out.gains).sum()), int(out.keep.sum())
    reason = _reason(cfg.recon, kept, len(planned), out.w, best, without, unchecked, out.unclear, other)
    if out.trend is not None:
        reason += _trend_reason(out.trend)
    if out.fill is not None:
        reason += _fill_reason(out.fill)
    if out.confirmation is not None:
        reason = _confirm_reason(out.confirmation, out.chosen, cfg.recon, reason)
    reason += _rounds_reason(rounds)
    return SelfCheck(
        recon=cfg.recon,
        plan=plan,
        validation=tuple(small.frames[i].name for f in out.folds for i in f.scored),
        psnr_without=without,
        psnr_by_weight=tuple(out.weights.items()),
        psnr_kept=best if kept else None,
        weight=out.w if kept else None,
        views=_view_checks(planned, out.gains, out.keep),
        reason=reason,
        fixer=None if fix is None else fix.record,
        psnr_other_seed=other,
        gap_trend=out.trend,
        confirmation=out.confirmation,
        pixel_weights=cfg.pixel_weights,
        rounds=rounds,
        fill_control=out.fill,
    )


def _rounds_reason(rounds: tuple[FixRound, ...]) -> str:
    """The later rounds of render -> fix -> refit in words (empty: none was tried)."""
    said = []
    for k, r in enumerate(rounds, 2):
        if r.psnr_after is None:
            said.append(f"round {k}'s fixer did not beat both its views and the renders it merges")
        else:
            verdict = "kept" if r.kept else "not kept"
            said.append(
                f"round {k} moved the folds' scored photos {r.psnr_before:.2f} -> {r.psnr_after:.2f} dB ({verdict})"
            )
    return f"; render -> fix -> refit: {'; '.join(said)}" if said else ""


def _written(
    small, planned, final, keep, record, first: _Fold, fixers: _Fixers, reference: Renderer | None, fits, cfg
) -> Checked:
    """The kept views as written: fixed with the render of ``reference`` (the fit on every input) when the
    first round's fixer is used, then through the later rounds (:func:`_replayed`, the inputs refitted with the
    kept views), their confidence lowered where they agree with the render of the first fold's fit."""
    raw, conf = images_and_confidence(final)
    images, idx = raw, np.flatnonzero(keep)
    if fixers.first is not None and reference is not None and len(idx):
        images = fixed(fixers.first, images, renders(reference, small, planned), conf)
    if fixers.later and reference is not None and len(idx):
        sub = None if conf is None else conf[idx]
        job = _Replay([planned[i] for i in idx], raw[idx], sub, images[idx], [], reference)
        [(last, reference)] = _replayed(fixers, small, [job], fits, cfg)
        images = np.array(images, np.float32)
        images[idx] = last
    fixer = fixers.last
    reference = reference if fixer is not None else None
    exported = _exported(images, conf, renders(first.base, small, planned), record.weight or 1.0, cfg)
    return Checked([planned[i] for i in idx], images[idx], exported[idx], record, fixer, reference)


def _view_checks(planned: list[Frame], gains: np.ndarray, keep: np.ndarray) -> tuple[ViewCheck, ...]:
    """One record per planned view; gain None where it could not be checked (NaN in ``gains``)."""
    return tuple(
        ViewCheck(f.name, float(f.index), None if np.isnan(g) else float(g), bool(k))
        for f, g, k in zip(planned, gains, keep)
    )


def _nothing_checkable(small: Scene, planned: list[Frame], final, fits: FitMany, cfg, plan: str) -> Checked:
    """The decision when no planned view can be checked (:func:`measuring_fold`): none is written."""
    held = validation_inputs(len(small))
    without = float(held_back_psnr(small, fits([validation_split(small, held)[1]])[0], held).mean())
    reason = (
        f"none of the {len(planned)} planned views lies where the held-back input photos can measure it (each "
        f"is between the neighbours of one): the capture is written without synthesized views"
    )
    log.warning("self-check: %s", reason)
    views = _view_checks(planned, np.full(len(planned), np.nan), np.zeros(len(planned), bool))
    names = tuple(small.frames[i].name for i in held)
    record = SelfCheck(cfg.recon, plan, names, without, (), None, None, views, reason)
    images, _ = images_and_confidence(final)
    return Checked([], images[:0], np.zeros(images[:0].shape[:3], np.float32), record)


def checked_views(
    inputs: Scene,
    paper: list[Frame],
    plan: PlanConfig,
    synth: SynthFn,
    cfg: SelfCheckConfig,
    sources: Scene | None = None,
    fits: FitMany | None = None,
    other: FitMany | None = None,
) -> tuple[list[Frame], Checked, Synthesized | np.ndarray]:
    """What ``densify --recon cfg.recon`` writes: (the planned frames, the kept views, the network's answer
    for every planned frame). The poses are ``paper`` (the paper's plan) or, where :func:`plan_of` is weak,
    :func:`weakest_plan`'s; the views are synthesized from ``sources`` (default: ``inputs``) and kept by
    :func:`self_check` on ``inputs``; ``fits``: how the fits run (default: :func:`check_fits` in a pool of
    :func:`check_workers` processes), ``other``: at the second seed (default: :func:`other_seed`'s fits in
    that pool, when ``fits`` is not given)."""
    if fits is None:
        with FitPool(check_workers(cfg)) as pool:
            cfg, reach = _reach_chosen(inputs, cfg, pool)
            second = other_seed(cfg)
            other = None if second is None else check_fits(second, pool)
            fits = remembering(check_fits(cfg, pool))  # e.g. the confirmation's bases, when a second way decides
            targets, checked, final = checked_views(inputs, paper, plan, synth, cfg, sources, fits, other)
            return targets, _with_reach(checked, reach), final
    mode = plan_of(cfg)
    targets = weakest_plan(at_check_size(inputs, cfg), plan, fits, cfg.gain_gap) if mode == "weak" else paper
    final = synth(inputs if sources is None else sources, targets)
    return targets, self_check(inputs, targets, synth, final, cfg, mode, fits, other), final


def _reach_chosen(inputs: Scene, cfg: SelfCheckConfig, pool: FitPool) -> tuple[SelfCheckConfig, ReachChoice | None]:
    """``cfg`` with the one reach of several that :func:`choose_reach` picks for its fits at the check size, and
    the choice (None: one reach given, or one that changes nothing on this capture)."""
    fitter = Fitter(cfg.recon, check_settings(cfg))
    if not reach_to_choose(fitter, cfg.far_reach):
        return cfg, None
    choice = choose_reach(at_check_size(inputs, cfg), fitter, cfg.far_reach, cfg.check_seed, pool)
    if choice is None:
        return cfg, None
    log.info("self-check: %s starts its random points to %gx the sparse points' far depth", cfg.recon, choice.reach)
    return replace(cfg, far_reach=(choice.reach,)), choice


def _with_reach(checked: Checked, choice: ReachChoice | None) -> Checked:
    """``checked`` whose record names the reach its fits started with and how it was chosen."""
    if choice is None or checked.record is None:
        return checked
    tried = tuple((float(r), p) for r, p in choice.validation_psnr.items())
    said = ", ".join(f"{r:g}x {p:.2f}" for r, p in tried)
    reason = (
        f"{checked.record.reason}; random starting points to {choice.reach:g}x the sparse points' far depth ({said} dB)"
    )
    record = replace(checked.record, far_reach=choice.reach, psnr_by_far_reach=tried, reason=reason)
    return replace(checked, record=record)


def _fitted_confidence(images: np.ndarray, conf: np.ndarray | None, reference: np.ndarray, cfg) -> np.ndarray | None:
    """The per-pixel weights (T, H, W) a fold's views are fitted with: :func:`informative_confidence`, or
    None (every pixel alike) with ``cfg.pixel_weights`` uniform."""
    return None if pixel_weights_of(cfg) == "uniform" else informative_confidence(images, conf, reference, cfg)


def _exported(images: np.ndarray, conf: np.ndarray | None, reference: np.ndarray, weight: float, cfg) -> np.ndarray:
    """The written views' confidence: the network's, lowered where the view agrees with the render of the fit
    without views (at that fit's size, then scaled up), times the synthetic-frame weight (that weight alone
    with ``cfg.pixel_weights`` uniform)."""
    if pixel_weights_of(cfg) == "uniform":
        return np.full(images.shape[:3], np.clip(weight, 0.0, 1.0), np.float32)
    h, w = reference.shape[1:3]
    factor = informative_confidence(resize_images(images, (w, h)), None, reference, cfg)
    factor = np.clip(resize_images(factor, (images.shape[2], images.shape[1])), 0.0, 1.0)
    base = np.ones(images.shape[:3], np.float32) if conf is None else np.asarray(conf, np.float32)
    return np.clip(base * factor * weight, 0.0, 1.0).astype(np.float32)


def _pixel_reason(tried: tuple[tuple[str, float], ...], cfg, given_up: _Outcome | None) -> str:
    """How the pixel weights were chosen (``given_up``: the outcome with the other ones, which scored higher
    on the held-back photos but kept no view; None: there was none)."""
    others = ", ".join(f"{m} {p:.2f}" for m, p in tried if m != cfg.pixel_weights)
    if given_up is None:
        return f"; {cfg.pixel_weights} pixel weights, chosen on the held-back photos (the fits with {others} dB)"
    c, why = given_up.confirmation, "kept no view"
    if c is not None and not c.confirmed:
        why = f"their {given_up.chosen} views were not confirmed ({_confirm_change(c.gains)})"
    head = f"; {cfg.pixel_weights} pixel weights: the fits with {others} dB scored higher on the held-back photos, "
    return head + f"but {why}"


def _trend_reason(trend: GapTrend) -> str:
    if trend.interior_kept:
        return ""
    return (
        f"; none between the inputs is kept: their gain there, {trend.gain_two_wide:+.2f} dB in gaps two inputs "
        f"wide and {trend.gain_three_wide:+.2f} in gaps three wide, extrapolates to {trend.gain_one_wide:+.2f} "
        f"in the final fit's"
    )


def _reason(
    recon: str,
    kept: int,
    planned: int,
    w: float,
    best: float,
    without: float,
    unchecked: int,
    unclear: bool,
    other: float | None = None,
) -> str:
    aside = f" ({unchecked} planned between the neighbours of a held-back photo could not be checked)" * (unchecked > 0)
    seed = "" if other is None else f", {other:.2f} dB at another seed"
    if kept == 0:
        return (
            f"no synthesized view {'clearly ' * unclear}improves the {recon} fit on the held-back input photos "
            f"({without:.2f} dB without views{seed}){aside}: the capture is written without synthesized views"
        )
    return (
        f"kept {kept} of {planned} synthesized views at weight {w:g}: the {recon} fit renders the "
        f"held-back input photos at {best:.2f} dB with them, {without:.2f} dB without{aside}"
    )
