"""The synthetic-frame weight, chosen on the inputs alone: fits without every ``VALIDATION_EVERY``-th interior
input, scored on those held-back inputs, with views synthesized again without them."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from sparself.capture.scene import Frame, Scene
from sparself.core import metrics
from sparself.core.errors import ConfigError
from sparself.evaluation.config import VALIDATION_EVERY
from sparself.evaluation.instruments import SynthFn, fit_each, images_and_confidence, with_images
from sparself.evaluation.results import WeightChoice
from sparself.recon import Renderer


def weighted_scene(
    scene: Scene, planned: list[Frame], images: np.ndarray, confidence: np.ndarray | None, weight: float
) -> Scene:
    """``scene`` + synthesized frames carrying their confidence maps (None: weight only) and loss ``weight``."""
    sc = with_images(scene, planned, images, confidence)
    return replace(sc, frames=[replace(f, weight=float(weight)) if f.synthetic else f for f in sc.frames])


def validation_inputs(n: int) -> list[int]:
    """Positions among n input views held back to choose the synthetic-frame weight: every
    VALIDATION_EVERY-th interior one from the third (the middle one when that gives none).

    >>> validation_inputs(25)
    [2, 7, 12, 17, 22]
    """
    return list(range(2, n - 1, VALIDATION_EVERY)) or ([n // 2] if n >= 3 else [])


def validation_split(inputs: Scene, held: Sequence[int] | None = None) -> tuple[list[int], Scene]:
    """(the held-back positions, the inputs without them) for choosing the weight; ``held`` defaults to
    :func:`validation_inputs`."""
    val = validation_inputs(len(inputs)) if held is None else list(held)
    if not val:
        raise ConfigError(f"{len(inputs)} input views leave none to choose the synthetic-frame weight on")
    return val, inputs.without(val)


@dataclass
class ValidationViews:
    """The planned views that the weight-choosing fits train on, and the names of the source views they
    were synthesized from."""

    images: np.ndarray  # (T, H, W, 3)
    confidence: np.ndarray | None  # (T, H, W)
    sources: list[str]


def validation_views(
    inputs: Scene, planned: list[Frame], synth: SynthFn, held: Sequence[int] | None = None
) -> ValidationViews:
    """The planned views synthesized by ``synth`` from the inputs minus the held-back ones, so no pixel of a
    held-back view reaches the validation fits through them (the network's weights, trained on all inputs,
    did see them: this removes the leak through the images, not through training). ``held``: as in
    :func:`validation_split`."""
    _, train = validation_split(inputs, held)
    images, confidence = images_and_confidence(synth(train, planned))
    return ValidationViews(images, confidence, [f.name for f in train.frames])


def held_back_psnr(inputs: Scene, renderer: Renderer, held: Sequence[int] | None = None) -> np.ndarray:
    """PSNR of ``renderer`` at each held-back view of ``inputs`` (their own photos), in order; ``held``: as in
    :func:`validation_split`."""
    val = validation_inputs(len(inputs)) if held is None else list(held)
    return np.array(
        [metrics.psnr(renderer.render(inputs.frames[i].pose, inputs.camera(i)), inputs.load(i)) for i in val]
    )


def weight_scenes(
    inputs: Scene,
    planned: list[Frame],
    views: ValidationViews,
    grid: Sequence[float],
    held: Sequence[int] | None = None,
) -> list[Scene]:
    """For each synthetic-frame weight of ``grid``: the inputs minus the held-back ones (``held``: as in
    :func:`validation_split`) + the planned ``views`` at that weight. ``views`` must be synthesized without
    the held-back inputs (:func:`validation_views`), or their pixels would favour larger weights: refused."""
    val, train = validation_split(inputs, held)
    leaked = sorted(set(views.sources) & {inputs.frames[i].name for i in val})
    if leaked:
        raise ValueError(f"validation views synthesized from held-back input(s) {leaked}")
    return [weighted_scene(train, planned, views.images, views.confidence, w) for w in grid]


def weight_scores(
    inputs: Scene,
    planned: list[Frame],
    views: ValidationViews,
    grid: Sequence[float],
    fit: Callable[[Scene], Renderer],
    held: Sequence[int] | None = None,
) -> dict[float, np.ndarray]:
    """For each synthetic-frame weight of ``grid``: the :func:`held_back_psnr` of a fit on
    :func:`weight_scenes`' scene (all fitted at once, :func:`fit_each`). Reads the inputs' pixels only, never a
    held-out photo."""
    val, _ = validation_split(inputs, held)
    scenes = weight_scenes(inputs, planned, views, grid, val)
    return {float(w): held_back_psnr(inputs, r, val) for w, r in zip(grid, fit_each(fit, scenes))}


def choose_weight(
    inputs: Scene, planned: list[Frame], views: ValidationViews, grid: Sequence[float], fit: Callable[[Scene], Renderer]
) -> WeightChoice:
    """The synthetic-frame weight of ``grid`` whose fit on the inputs minus :func:`validation_inputs` (+ the
    planned ``views``) renders those held-back *input* views best (mean PSNR; the first on ties), as
    :func:`weight_scores` measures it."""
    val = validation_inputs(len(inputs))
    scores = {w: float(np.mean(v)) for w, v in weight_scores(inputs, planned, views, grid, fit).items()}
    best = max(scores, key=lambda w: scores[w])
    return WeightChoice(
        best,
        {str(w): v for w, v in scores.items()},
        [inputs.frames[i].name for i in val],
        list(views.sources),
        views.confidence is not None,
    )
