"""How far the CPU 3DGS starts its random Gaussians past a capture's sparse points, chosen on the inputs alone:
one fit per tried reach on the inputs minus every ``VALIDATION_EVERY``-th interior one, scored on those
held-back inputs. A reach that helps one capture can cost another dB (docs/results.md), and nothing in the
camera layout tells them apart, so the capture's own photos decide."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from sparself.capture.scene import Scene
from sparself.evaluation.results import ReachChoice
from sparself.evaluation.weighting import held_back_psnr, validation_inputs, validation_split
from sparself.recon.common import start_depths
from sparself.recon.pool import FitPool, Fitter, fit_all


def reach_to_choose(fit: Fitter, reaches: Sequence[float]) -> bool:
    """Whether there is a reach to choose for ``fit``: several are given and it takes one (the CPU 3DGS's
    settings carry ``far_reach``; gsplat, the NeRF and the MPI take none)."""
    return len(reaches) > 1 and "far_reach" in fit.settings


def reach_matters(scene: Scene, reaches: Sequence[float]) -> bool:
    """Whether the reaches start ``scene``'s random points at different depths: only where its depth bounds
    come from its sparse points (:func:`~sparself.recon.common.start_depths`)."""
    return len({start_depths(scene, float(r)) for r in reaches}) > 1


def choose_reach(
    inputs: Scene, fit: Fitter, reaches: Sequence[float], seed: int, pool: FitPool | None = None
) -> ReachChoice | None:
    """The reach of ``reaches`` whose fit (``fit`` with that ``far_reach`` and reconstruction seed ``seed``) on
    the inputs minus :func:`~sparself.evaluation.weighting.validation_inputs` renders those held-back inputs
    best (mean PSNR; the first on ties). None where the reaches make no difference to where the fits start
    (:func:`reach_matters`), or too few inputs hold one back, so nothing is fitted. Reads the inputs' pixels
    only, never a held-out photo."""
    if not validation_inputs(len(inputs)):
        return None
    val, train = validation_split(inputs)
    if not reach_matters(train, reaches):
        return None
    fitters = [fit.with_settings(far_reach=float(r), seed=seed) for r in reaches]
    renderers = fit_all(fitters, [train] * len(fitters), pool)
    scores = [float(np.mean(held_back_psnr(inputs, r, val))) for r in renderers]
    best = int(np.argmax(scores))  # the first of equal scores
    return ReachChoice(
        float(reaches[best]),
        {str(float(r)): s for r, s in zip(reaches, scores)},
        [inputs.frames[i].name for i in val],
        seed,
    )
