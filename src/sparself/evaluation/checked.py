"""'N + sparself, checked': the protocol's measure of what ``densify --recon R`` writes for reconstructor R.

Per network seed, the views are planned where R is weak, fixed, and kept only where they raise R's PSNR on
held-back *input* photos (:func:`sparself.evaluation.selfcheck.checked_views`, which never reads a held-out
photo); R is then fitted on the inputs + the kept views at their exported confidence and scored on the
held-out photos like every other row. When the self-check keeps nothing, the capture is the N photos alone
and the row is the N-only fit. Where the fixer was used, its views at the held-out poses are scored too
(``sparself_fixed_views``): the fixer is meant to beat both the network's views and the N-only render.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Callable, Literal

from sparself.capture.scene import Scene
from sparself.evaluation.fixing import fixed
from sparself.evaluation.instruments import fit_each, renders, with_images
from sparself.evaluation.results import NETWORK_CHECKED, NETWORK_FIXED, ReconResult, ScoredSet, SeededSets
from sparself.evaluation.scene_eval import SceneEval
from sparself.evaluation.selfcheck import (
    Checked,
    SelfCheckConfig,
    at_check_size,
    check_cameras,
    check_fits,
    check_workers,
    checked_views,
    remembering,
)
from sparself.recon import Renderer
from sparself.recon.pool import FitPool
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


def check_config(ev: SceneEval, rname: str) -> SelfCheckConfig | None:
    """The self-check ``densify --recon`` runs for reconstructor ``rname`` (None: it has none)."""
    recon = CHECKED_AS.get(rname)
    if recon is None or not ev.cfg.checked or not ev.net_synths:
        return None
    return SelfCheckConfig(
        recon=recon, plan_mode=ev.cfg.check_plan, check_steps=ev.cfg.check_steps, check_seed=ev.cfg.recon_seed
    )


def _fixed_targets(ev: SceneEval, k: int, checked: Checked, cfg: SelfCheckConfig, label: str, fits) -> ScoredSet | None:
    """The seed's network views at the held-out poses through the fixer, merged with the renders there of the
    fit on every input at the check size (the one the written views were merged with; fitted here, once per
    capture through ``fits``, when no view was kept). None: no fixer was used."""
    if checked.fixer is None:
        return None
    reference = checked.reference or fits([at_check_size(ev.inputs, cfg)])[0]
    imgs, conf = ev.net_targets[k]
    out = fixed(checked.fixer, imgs, renders(reference, check_cameras(ev.full, cfg), ev.targets), conf)
    return ev.score(out, label, ev.scored, seed=ev.cfg.first_seed + k)


def checked_fits(
    ev: SceneEval, rname: str, fit: Callable[[Scene], Renderer], entry: ReconResult, base: ScoredSet
) -> None:
    """Per seed: what densify writes for ``rname``, fitted and scored on the held-out photos, into
    ``entry``'s NETWORK_CHECKED row (each seed's self-check record as its decision), and the fixer's views
    into its NETWORK_FIXED row where it was used."""
    cfg = check_config(ev, rname)
    if cfg is None:
        return
    plan = PlanConfig(n_mid=ev.cfg.n_mid, n_extra=ev.cfg.n_extra, order="capture")
    sets, views = SeededSets(), SeededSets()
    with FitPool(check_workers(cfg)) as pool:
        fits = remembering(check_fits(cfg, pool))  # the fits without views recur with every seed
        done = [checked_views(ev.inputs, ev.planned, plan, synth, cfg, fits=fits)[1] for synth in ev.net_synths]
        fixed_views = [
            _fixed_targets(ev, k, c, cfg, f"{NETWORK_FIXED} ({rname}) seed {ev.cfg.first_seed + k}", fits)
            for k, c in enumerate(done)
        ]
    kept = [k for k, c in enumerate(done) if c.frames]
    scenes = [with_images(ev.inputs, done[k].frames, done[k].images, done[k].confidence) for k in kept]
    fitted = dict(zip(kept, fit_each(fit, scenes)))
    for k, checked in enumerate(done):
        seed = ev.cfg.first_seed + k
        label = f"{rname} ({NETWORK_CHECKED} seed {seed})"
        if k in fitted:
            views_n = len(ev.inputs) + len(checked.frames)
            scored = ev.score(renders(fitted[k], ev.full, ev.targets), label, ev.scored, seed=seed, views=views_n)
        else:  # nothing kept: the capture is the N photos, and so is its fit
            scored = replace(base, seed=seed)
        scored.decision = checked.record
        sets.per_seed.append(scored)
        fx = fixed_views[k]
        if fx is not None:
            views.per_seed.append(fx)
    entry.rows[NETWORK_CHECKED] = sets
    if views.per_seed:
        entry.rows[NETWORK_FIXED] = views
