"""The protocol's second question: each reconstructor fitted on the N inputs, on N + synthesized views (plain
and weighted), and on the oracle, scored on the held-out photos; the oracle share."""

from __future__ import annotations

import logging
import time
from typing import Callable

import numpy as np
from tqdm.auto import tqdm

from sparself.capture.scene import Scene
from sparself.evaluation.checked import checked_fits
from sparself.evaluation.instruments import (
    fit_each,
    fit_seed,
    fits_at_once,
    paired,
    reconstructor,
    renders,
    with_fit_seed,
    with_images,
)
from sparself.evaluation.reach import choose_reach, reach_to_choose
from sparself.evaluation.results import (
    BASE,
    NETWORK,
    NETWORK_CHECKED,
    NETWORK_WEIGHTED,
    ORACLE,
    ReconResult,
    RowError,
    ScoredSet,
    SeededSets,
)
from sparself.evaluation.scene_eval import SceneEval
from sparself.evaluation.weighting import choose_weight, validation_views, weighted_scene
from sparself.recon import Renderer
from sparself.recon.pool import FitPool, Fitter

log = logging.getLogger(__name__)


def oracle_scene(ev: SceneEval) -> Scene:
    """The inputs plus the real photos at the snapped planned poses (planned poses without one, e.g.
    extrapolations with no extrapolation margin, keep the network's seed-0 views, where it ran)."""
    fill = ev.net_planned[0] if ev.net_planned else None
    imgs, extra = [], []
    for k, f in enumerate(ev.planned):
        if k in ev.mid_truth:
            # a real, non-held-out photo at exactly this pose (a between or margin frame, never an evaluation frame)
            imgs.append(ev.full.load(ev.mid_truth[k]))
            extra.append(f)
        elif fill is not None:
            imgs.append(fill[k])
            extra.append(f)
    return with_images(ev.inputs, extra, imgs)


def densified_scenes(ev: SceneEval, seeds: list[int]) -> list[tuple[str, int, Scene]]:
    """(key, seed, scene) for every reconstruction: per seed of ``seeds``, N alone, each densify-baseline's
    views and the oracle; N + each network seed's views (with that seed)."""
    runs: list[tuple[str, int, Scene]] = [(BASE, s, ev.inputs) for s in seeds]
    for seed, imgs in enumerate(ev.net_planned, start=ev.cfg.first_seed):
        runs.append((NETWORK, seed, with_images(ev.inputs, ev.planned, imgs)))
    for b in ev.cfg.densify_baselines:
        if b in ev.baseline_planned:
            runs += [(b, s, with_images(ev.inputs, ev.planned, ev.baseline_planned[b])) for s in seeds]
    if ev.cfg.oracle and ev.split.kind == "dense" and ev.mid_truth:
        oracle = oracle_scene(ev)
        runs += [(ORACLE, s, oracle) for s in seeds]
    return runs


def reconstruct(ev: SceneEval, rname: str, fit: Callable[[Scene], Renderer], entry: ReconResult) -> None:
    """Fit ``rname`` on every densified scene and score its renders at the held-out poses, into ``entry``
    (which keeps what was done if a fit fails: the seeds fitted so far, unsummarised). Every row is per seed,
    fitted with that seed's reconstruction seed; a reconstructor that takes no seed fits the rows without
    the network's views once (a single set, as without seeds). The rows' fits and the self-check's share one
    pool: its workers start, and compile the CPU 3DGS, once."""
    with FitPool(fits_at_once(fit)) as pool:
        _fitted_rows(ev, rname, reach_chosen(ev, fit, entry, pool), entry, pool)


def reach_chosen(ev: SceneEval, fit: Callable[[Scene], Renderer], entry: ReconResult, pool: FitPool) -> Callable:
    """``fit`` with the CPU 3DGS's reach :func:`~sparself.evaluation.reach.choose_reach` picks on the inputs
    (recorded in ``entry``) where the run tries several; ``fit`` itself otherwise. It is chosen with network
    seed 0's reconstruction seed whatever the run's first seed, so that a batch's seed units agree."""
    reaches = ev.cfg.splat_far_reach
    if not isinstance(fit, Fitter) or not reach_to_choose(fit, reaches):
        return fit
    entry.reach = choose_reach(ev.inputs, fit, reaches, fit_seed(ev.cfg, 0), pool)
    if entry.reach is None:
        return fit
    log.info(
        "%s: %s starts its random points to %gx the sparse points' far depth", ev.name, fit.name, entry.reach.reach
    )
    return fit.with_settings(far_reach=entry.reach.reach)


def _fitted_rows(
    ev: SceneEval, rname: str, fit: Callable[[Scene], Renderer], entry: ReconResult, pool: FitPool
) -> None:
    seeds, each = ev.cfg.seed_list, paired(fit)
    runs = densified_scenes(ev, seeds if each else seeds[:1])
    fitted = fit_each(fit, [sc for _, _, sc in runs], [fit_seed(ev.cfg, s) for _, s, _ in runs], pool)
    for (key, seed, sc), renderer in tqdm(
        zip(runs, fitted), total=len(runs), desc=f"{ev.name}: {rname} fits", disable=not ev.cfg.progress, leave=False
    ):
        if not entry.fitted:
            entry.fitted, entry.backend = True, getattr(renderer, "backend", None)
        per_seed = key == NETWORK or each
        label = f"{rname} {len(sc)} views ({f'{key} seed {seed}' if per_seed else key})"
        example = key == NETWORK or seed == seeds[0]  # the other rows' images differ by seed only in noise
        scored = ev.score(
            render_targets(ev, renderer),
            label,
            ev.scored,
            seed=seed if per_seed else None,
            views=len(sc),
            example=example,
        )
        if per_seed:
            row = entry.rows.setdefault(key, SeededSets(summarized=False))
            assert isinstance(row, SeededSets)
            row.per_seed.append(scored)
        else:
            entry.rows[key] = scored
    for row in entry.rows.values():
        if isinstance(row, SeededSets):
            row.summarized = True
    if ev.cfg.weighted and ev.net_planned:
        try:
            weighted_fits(ev, rname, fit, entry, pool)
        except Exception as e:  # the plain results stand without it
            log.warning("%s: %s weighted densification failed: %s", ev.name, rname, e)
            entry.rows[NETWORK_WEIGHTED] = RowError(f"{type(e).__name__}: {e}")
    base = entry.rows.get(BASE)
    if isinstance(base, (SeededSets, ScoredSet)):
        by_seed = (
            {p.seed: p for p in base.per_seed if p.seed is not None}
            if isinstance(base, SeededSets)
            else dict.fromkeys(seeds, base)
        )
        try:
            checked_fits(ev, rname, fit, entry, by_seed, pool)
        except Exception as e:  # the other rows stand without it
            log.warning("%s: %s checked densification failed: %s", ev.name, rname, e)
            entry.rows[NETWORK_CHECKED] = RowError(f"{type(e).__name__}: {e}")
    entry.check_instrument()
    entry.status = "ok"


def render_targets(ev: SceneEval, renderer) -> np.ndarray:
    """The renderer's images at the scored held-out poses (poses only: no pixels reach it)."""
    return renders(renderer, ev.full, ev.targets)


def weighted_fits(
    ev: SceneEval, rname: str, fit: Callable[[Scene], Renderer], entry: ReconResult, pool: FitPool | None = None
) -> None:
    """'N + sparself, weighted': per seed, the inputs + its views (synthesized from all inputs) with their
    confidence as per-pixel loss weights and the synthetic-frame weight :func:`choose_weight` picked on the
    run's first seed (its network's views synthesized again without the held-back inputs)."""
    if ev.validation is None:
        ev.validation = validation_views(ev.inputs, ev.planned, ev.net_synths[0])
    first = with_fit_seed(fit, fit_seed(ev.cfg, ev.cfg.first_seed))
    choice = choose_weight(ev.inputs, ev.planned, ev.validation, ev.cfg.synthetic_weights, first)
    choice.chosen_on_seed = ev.cfg.first_seed
    sets = SeededSets()
    seeds = ev.cfg.seed_list[: len(ev.net_planned)]
    scenes = [weighted_scene(ev.inputs, ev.planned, v, c, choice.weight) for v, c in zip(ev.net_planned, ev.net_conf)]
    for seed, sc, r in zip(seeds, scenes, fit_each(fit, scenes, [fit_seed(ev.cfg, s) for s in seeds], pool)):
        label = f"{rname} {len(sc)} views ({NETWORK_WEIGHTED} seed {seed})"
        scored = ev.score(render_targets(ev, r), label, ev.scored, seed=seed, views=len(sc))
        scored.decision = choice
        sets.per_seed.append(scored)
    entry.rows[NETWORK_WEIGHTED] = sets


def densification(ev: SceneEval, reconstructors: dict[str, Callable[[Scene], Renderer]] | None) -> None:
    """Each reconstructor from N views vs N + synthesized views vs the oracle; a failure is recorded."""
    recs = reconstructors if reconstructors is not None else {}
    dens: dict[str, ReconResult] = {}
    ev.result.densification = dens
    for rname in ev.cfg.reconstructors if reconstructors is None else list(recs):
        t0 = time.perf_counter()
        entry = dens[rname] = ReconResult()
        try:
            reconstruct(ev, rname, recs[rname] if rname in recs else reconstructor(rname, ev.cfg), entry)
        except Exception as e:
            log.warning("%s: reconstructor %s failed: %s", ev.name, rname, e)
            entry.status, entry.error = "failed", f"{type(e).__name__}: {e}"
        entry.seconds = time.perf_counter() - t0
        ev.partial()
