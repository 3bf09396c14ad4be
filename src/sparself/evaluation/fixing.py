"""The fixer on a capture (:mod:`sparself.model.fixer`): trained and tested on the held-back input photos,
used only where its merge beats both the network's views and the reconstruction's render there.

Training pairs are honest by construction: at each held-back input photo, the render comes from a fit
without it and the view is synthesized without it (the network's weights did train on every input, as for
the weight choice of :mod:`sparself.evaluation.weighting`). Each held-back photo is scored by a fixer
trained without it: by one trained on the other self-check folds' photos (the very fixers that then fix each
fold's views), or leave-one-out when there is one fold; the fixer that is used on the written views is then
trained on all of them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
import torch

from sparself.capture.images import resize_images
from sparself.capture.io.dense import FixerCheck
from sparself.capture.scene import Scene
from sparself.core import metrics
from sparself.evaluation.instruments import renders
from sparself.model.fixer import Fixer, blend, fix_views, train_fixer
from sparself.recon import Renderer

log = logging.getLogger(__name__)
MIN_GAIN = 0.05  # dB the merges must beat both the views and the renders by at least (a copy of the render ties)


@dataclass
class FixerFit:
    """A capture's fixer (None: not used), its test on the held-back inputs, and the fixers that scored each
    group of pairs in that test, each trained without its group (in the order of the groups)."""

    fixer: Fixer | None
    record: FixerCheck
    held_out: tuple[Fixer, ...] = ()


def to_tensor(images: np.ndarray) -> torch.Tensor:
    """(T, H, W, 3) or (T, H, W) numpy -> (T, C, H, W) float32 tensor."""
    a = np.asarray(images, np.float32)
    return torch.from_numpy(a[..., None] if a.ndim == 3 else a).permute(0, 3, 1, 2).contiguous()


def fixed(fixer: Fixer, views: np.ndarray, reference: np.ndarray, confidence: np.ndarray | None) -> np.ndarray:
    """(T, H, W, 3) views fixed with renders ``reference`` (T, h, w, 3) at the same poses (any smaller size)."""
    conf = np.ones(views.shape[:3], np.float32) if confidence is None else confidence
    with torch.no_grad():
        out = fix_views(fixer, to_tensor(views), to_tensor(reference), to_tensor(conf))
    return out.permute(0, 2, 3, 1).numpy().astype(np.float32)


@dataclass
class FixerPairs:
    """Training pairs at held-back input photos, each (P, C, h, w) at the check size: the view synthesized
    without the photo, the render of a fit without it, the view's confidence and the photo itself."""

    names: tuple[str, ...]
    view: torch.Tensor
    render: torch.Tensor
    confidence: torch.Tensor
    truth: torch.Tensor

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, idx: list[int]) -> "FixerPairs":
        t = (self.view[idx], self.render[idx], self.confidence[idx], self.truth[idx])
        return FixerPairs(tuple(self.names[i] for i in idx), *t)

    @staticmethod
    def cat(parts: list["FixerPairs"]) -> "FixerPairs":
        t = (torch.cat([getattr(q, k) for q in parts]) for k in ("view", "render", "confidence", "truth"))
        return FixerPairs(tuple(n for q in parts for n in q.names), *t)

    def train(self, steps: int, seed: int) -> Fixer:
        return train_fixer(self.view, self.render, self.confidence, self.truth, steps=steps, seed=seed)


def fixer_pairs(
    small: Scene, held: list[int], base: Renderer, views: np.ndarray, confidence: np.ndarray | None
) -> FixerPairs:
    """The pairs at ``small``'s positions ``held``: ``views`` (P, H, W, 3, any size) and their ``confidence``
    (P, H, W or None) synthesized there without those photos, renders of ``base`` (a fit without them)."""
    cam = small.camera(held[0])
    size = (cam.width, cam.height)
    v = resize_images(views, size)
    c = np.ones(v.shape[:3], np.float32) if confidence is None else resize_images(confidence, size)
    rend = renders(base, small, [small.frames[i] for i in held])
    truth = np.stack([small.load(i) for i in held])
    return FixerPairs(tuple(small.frames[i].name for i in held), *(to_tensor(a) for a in (v, rend, c, truth)))


def refit_pairs(pairs: FixerPairs, small: Scene, held: list[int], fit: Renderer) -> FixerPairs:
    """``pairs`` (at ``small``'s positions ``held``) with the renders of ``fit`` there instead: the same views
    and photos, the render of another fit without those photos (one with synthesized views, for a later round)."""
    return replace(pairs, render=to_tensor(renders(fit, small, [small.frames[i] for i in held])))


def _psnrs(pred: torch.Tensor, truth: torch.Tensor) -> np.ndarray:
    return np.array([metrics.psnr(p.permute(1, 2, 0).numpy(), t.permute(1, 2, 0).numpy()) for p, t in zip(pred, truth)])


def _mean_psnr(pred: torch.Tensor, truth: torch.Tensor) -> float:
    return float(np.mean(_psnrs(pred, truth)))


def beats(fixed: np.ndarray, view: np.ndarray, render: np.ndarray) -> bool:
    """Whether the merges beat both the views and the renders (PSNR per photo, each (P,)): their mean gain
    over the better of the two (by mean) exceeds MIN_GAIN and the standard error of that gain over the
    photos, so that a few photos that happen to favour the merge do not decide.

    >>> beats(np.array([21.0, 22.0]), np.array([20.0, 21.0]), np.array([19.0, 19.0]))
    True
    >>> beats(np.array([22.0, 20.2]), np.array([20.0, 21.0]), np.array([19.0, 19.0]))  # +0.6 +- 1.4
    False
    >>> inf = np.array([np.inf, np.inf])  # exact on both: nothing to gain
    >>> beats(inf, inf, np.array([19.0, 19.0]))
    False
    """
    return metrics.clear_gain(metrics.gain(fixed, view if view.mean() >= render.mean() else render), MIN_GAIN)


def validated_fixer(pairs: FixerPairs, steps: int, seed: int, groups: list[list[int]] | None = None) -> FixerFit:
    """Score each group of pairs (positions into ``pairs``; default: each pair alone, leave-one-out) with a
    fixer trained on the other groups' pairs; when those merges beat both the views and the renders
    (:func:`beats`), the fixer trained on every pair. Needs two groups."""
    v, r, c, t = pairs.view, pairs.render, pairs.confidence, pairs.truth
    groups = [[j] for j in range(len(pairs))] if groups is None else [g for g in groups if g]
    if sorted(j for g in groups for j in g) != list(range(len(pairs))):
        raise ValueError(f"the groups {groups} do not split the {len(pairs)} pairs")
    if len(groups) < 2:
        return FixerFit(None, FixerCheck(pairs.names, _mean_psnr(v, t), _mean_psnr(r, t), float("nan"), False))
    held_out, merged = [], torch.zeros_like(t)
    for g in groups:
        fx = pairs.subset([k for k in range(len(pairs)) if k not in g]).train(steps, seed)
        with torch.no_grad():
            merged[g] = blend(fx, v[g], r[g], c[g])
        held_out.append(fx)
    each = _psnrs(v, t), _psnrs(r, t), _psnrs(merged, t)
    p_view, p_render, p_fixed = (float(e.mean()) for e in each)
    used = beats(each[2], each[0], each[1])
    log.info(
        "fixer on %d held-back inputs: views %.2f dB, render %.2f dB, fixed %.2f dB (%s)",
        len(pairs),
        p_view,
        p_render,
        p_fixed,
        "used" if used else "not used: it does not beat both by more than its spread over the photos",
    )
    fixer = pairs.train(steps, seed) if used else None
    return FixerFit(fixer, FixerCheck(pairs.names, p_view, p_render, p_fixed, used), tuple(held_out))
