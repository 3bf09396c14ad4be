"""'N + sparself, checked': the protocol's measure of what ``densify --recon R`` writes for reconstructor R.

Per network seed, the views are planned for R (:func:`~sparself.evaluation.selfcheck.plan_of`), fixed, and
kept only where they raise R's PSNR on held-back *input* photos
(:func:`sparself.evaluation.selfcheck.checked_views`, which never reads a held-out photo); R is then fitted on
the inputs + the kept views at their exported confidence and scored on the held-out photos like every other
row. When the self-check keeps nothing, the capture is the N photos alone and the row is the N-only fit. Where
the fixer was used, its views at the held-out poses are scored too
(``sparself_fixed_views``): the fixer is meant to beat both the network's views and the N-only render.
"""

from __future__ import annotations

import logging
from contextlib import nullcontext
from dataclasses import replace
from functools import partial
from typing import Callable, Literal

import numpy as np

from sparself.capture.scene import Frame, Scene
from sparself.core.metrics import gain
from sparself.evaluation.fixing import fixed
from sparself.evaluation.instruments import fit_each, fit_seed, fits_at_once, renders, with_images
from sparself.evaluation.results import AT_VIEWS, NETWORK_CHECKED, NETWORK_FIXED, ReconResult, ScoredSet, SeededSets
from sparself.evaluation.scene_eval import SceneEval
from sparself.evaluation.selfcheck import (
    Checked,
    FitMany,
    SelfCheckConfig,
    check_cameras,
    check_fits,
    check_settings,
    check_workers,
    checked_views,
    other_seed,
    remembering,
)
from sparself.recon import Renderer
from sparself.recon.pool import FitPool, Fitter
from sparself.synthesis.plan import PlanConfig

log = logging.getLogger(__name__)

# the evaluation's reconstructor -> densify's --recon that checks views for it
CHECKED_AS: dict[str, Literal["3dgs", "nerf", "mpi"]] = {
    "3dgs": "3dgs",
    "splat": "3dgs",
    "gsplat": "3dgs",
    "nerf": "nerf",
    "mpi": "mpi",
}


def check_config(ev: SceneEval, rname: str, seed: int, far_reach: float = 1.0) -> SelfCheckConfig | None:
    """The self-check ``densify --recon`` runs for reconstructor ``rname`` on network seed ``seed``, its fits
    seeded like that seed's rows and starting as far past the sparse points as theirs, ``far_reach`` (None:
    it has none)."""
    recon = CHECKED_AS.get(rname)
    if recon is None or not ev.cfg.checked or not ev.net_synths:
        return None
    return SelfCheckConfig(
        recon=recon,
        plan_mode=ev.cfg.check_plan,
        check_steps=ev.cfg.check_steps,
        check_size=ev.cfg.check_size,
        check_seed=fit_seed(ev.cfg, seed),
        gain_gap=ev.cfg.check_gain_gap,
        pixel_weights=ev.cfg.check_pixel_weights,
        keep=ev.cfg.check_keep,
        gap_trend=ev.cfg.check_gap_trend,
        confirm=ev.cfg.check_confirm,
        confirm_prune=ev.cfg.check_confirm_prune,
        loss_within_gain=ev.cfg.check_loss_within_gain,
        max_photo_loss=ev.cfg.check_max_photo_loss,
        ends_context=ev.cfg.check_ends_context,
        fill_control=ev.cfg.check_fill_control,
        fix_rounds=ev.cfg.check_fix_rounds,
        far_reach=(far_reach,),
    )


def _fixed_targets(ev: SceneEval, k: int, checked: Checked, cfg: SelfCheckConfig, label: str) -> ScoredSet | None:
    """The seed's network views at the held-out poses through the fixer, merged with the renders there of the
    check's fit on every input at the check size (the one its written views are merged with). None: no fixer
    was used."""
    if checked.fixer is None or checked.reference is None:
        return None
    imgs, conf = ev.net_targets[k]
    out = fixed(checked.fixer, imgs, renders(checked.reference, check_cameras(ev.full, cfg), ev.targets), conf)
    return ev.score(out, label, ev.scored, seed=ev.cfg.first_seed + k)


def checked_fits(
    ev: SceneEval,
    rname: str,
    fit: Callable[[Scene], Renderer],
    entry: ReconResult,
    base: dict[int, ScoredSet],
    rows_pool: FitPool | None = None,
) -> None:
    """Per seed: what densify writes for ``rname``, fitted and scored on the held-out photos, into
    ``entry``'s NETWORK_CHECKED row (each seed's self-check record as its decision), and the fixer's views
    into its NETWORK_FIXED row where it was used. ``base``: each seed's N-only fit, the row where nothing
    is kept. ``rows_pool``: the rows' pool, whose started workers the checks use where they would start as many."""
    seeds = ev.cfg.seed_list[: len(ev.net_synths)]
    reach = fit.settings.get("far_reach", 1.0) if isinstance(fit, Fitter) else 1.0
    first = check_config(ev, rname, seeds[0], reach) if seeds else None
    if first is None:
        return
    cfgs = [replace(first, check_seed=fit_seed(ev.cfg, s)) for s in seeds]
    plan = PlanConfig(n_mid=ev.cfg.n_mid, n_extra=ev.cfg.n_extra, order="capture")
    sets, views = SeededSets(), SeededSets()
    fixed_views: list[ScoredSet | None] = []
    workers = check_workers(first)
    with nullcontext(rows_pool) if rows_pool is not None and rows_pool.workers == workers else FitPool(workers) as pool:
        memos: dict[tuple, FitMany] = {}  # the fits without views recur with every seed of the same fit seed

        def fits_for(c: SelfCheckConfig) -> FitMany:
            key = tuple(sorted(check_settings(c).items()))
            memos[key] = memos.get(key) or remembering(check_fits(c, pool))
            return memos[key]

        tasks = []
        for synth, cfg, seed in zip(ev.net_synths, cfgs, seeds):
            fits, second = fits_for(cfg), other_seed(cfg)
            other = None if second is None else fits_for(second)  # the next seed's fits without views, once
            check = partial(checked_views, ev.inputs, ev.planned, plan, synth, cfg, fits=fits, other=other)
            tasks.append(partial(_checked_and_fitted, ev, check, fit, fit_seed(ev.cfg, seed), pool))
        # the seeds' self-checks are independent: their fits share the workers, and so does the fit of what a
        # seed writes, which then runs beside the other seeds' checks instead of after them
        done, fitted = zip(*pool.in_turns(tasks))
        for seed, checked, cfg in zip(seeds, done, cfgs):
            label = f"{NETWORK_FIXED} ({rname}) seed {seed}"
            fixed_views.append(_fixed_targets(ev, seed - ev.cfg.first_seed, checked, cfg, label))
    for k, (seed, checked, written) in enumerate(zip(seeds, done, fitted)):
        label = f"{rname} ({NETWORK_CHECKED} seed {seed})"
        if written is not None:
            views_n = len(ev.inputs) + len(checked.frames)
            scored = ev.score(renders(written, ev.full, ev.targets), label, ev.scored, seed=seed, views=views_n)
        else:  # nothing kept: the capture is the N photos, and so is its fit (that seed's)
            scored = replace(base[seed], seed=seed)
        scored.decision = checked.record
        sets.per_seed.append(scored)
        fx = fixed_views[k]
        if fx is not None:
            views.per_seed.append(fx)
    entry.rows[NETWORK_CHECKED] = sets
    note = _at_kept_views(ev, rname, [c.frames for c in done], sets.per_seed, base)
    if note:
        ev.result.notes.append(note)
    if views.per_seed:
        entry.rows[NETWORK_FIXED] = views


def _checked_and_fitted(
    ev: SceneEval,
    check: Callable[[], tuple[list[Frame], Checked, object]],
    fit: Callable[[Scene], Renderer],
    seed: int,
    pool: FitPool,
) -> tuple[Checked, Renderer | None]:
    """A seed's self-check (``check()``: :func:`checked_views`'s answer) and the fit, at reconstruction seed
    ``seed``, of the capture it writes: the inputs and its kept views (None when it keeps none). The fit goes
    to the check's ``pool`` where its reconstructor fits side by side (a GPU's fit stays in this process)."""
    _, checked, _ = check()
    if not checked.frames:
        return checked, None
    scene = with_images(ev.inputs, checked.frames, checked.images, checked.confidence)
    shared = pool if fits_at_once(fit) > 1 else None
    return checked, next(iter(fit_each(fit, [scene], [seed], shared)))


def _at_kept_views(
    ev: SceneEval, rname: str, kept: list[list[Frame]], rows: list[ScoredSet], base: dict[int, ScoredSet]
) -> str | None:
    """A note when scored frames lie at a kept view's pose (:meth:`SceneEval.at_views`): how many per seed, and
    the checked row's change over N at the other scored frames, which the views reach only through the
    reconstruction ("–" where there are none). None when no seed kept a view at a scored frame."""
    ats = [ev.at_views(frames) for frames in kept]
    if not any(at.any() for at in ats):
        return None
    counts, elsewhere = [], []
    for at, row in zip(ats, rows, strict=True):
        counts.append(f"{int(at.sum())}/{len(at)}")
        n_only = base[row.seed if row.seed is not None else ev.cfg.first_seed]
        gains = [float(gain(f.psnr, b.psnr)) for f, b, a in zip(row.frames, n_only.frames, at, strict=True) if not a]
        elsewhere.append(f"{np.mean(gains):+.2f}" if gains else "–")
    return (
        f"{AT_VIEWS}{rname}, N + sparself checked (what densify writes): scored frames at a kept view's pose per "
        f"seed {', '.join(counts)}; its change over N at the other scored frames {' / '.join(elsewhere)} dB"
    )
