"""The fixer on a capture (:mod:`sparself.model.fixer`): trained and tested on the held-back input photos,
used only where its merge beats both the network's views and the reconstruction's render there.

Training pairs are honest by construction: at each held-back input photo, the render comes from the fit on
the other inputs and the view is synthesized from the other inputs (the network's weights did train on
every input, as for the weight choice of :mod:`sparself.evaluation.weighting`). Each held-back photo is
scored by a fixer trained on the others; the fixer that is used is then trained on all of them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch

from sparself.capture.images import resize_images
from sparself.capture.io.dense import FixerCheck
from sparself.capture.scene import Frame, Scene
from sparself.core import metrics
from sparself.evaluation.instruments import SynthFn, images_and_confidence, renders
from sparself.evaluation.weighting import validation_split
from sparself.model.fixer import Fixer, blend, fix_views, train_fixer
from sparself.recon import Renderer

log = logging.getLogger(__name__)


@dataclass
class FixerFit:
    """A capture's fixer (None: not used) and its test on the held-back inputs."""

    fixer: Fixer | None
    record: FixerCheck


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


def _held_back_pairs(inputs: Scene, small: Scene, base: Renderer, synth: SynthFn) -> tuple[list[int], list]:
    """(held-back positions, [view, render, confidence, truth] tensors at ``small``'s size)."""
    val, train = validation_split(inputs)
    cam = small.camera(val[0])
    targets = [inputs.frames[i] for i in val]
    imgs, conf = images_and_confidence(synth(train, targets))
    views = resize_images(imgs, (cam.width, cam.height))
    conf = np.ones(views.shape[:3], np.float32) if conf is None else resize_images(conf, (cam.width, cam.height))
    small_targets: list[Frame] = [small.frames[i] for i in val]
    rend = renders(base, small, small_targets)
    truth = np.stack([small.load(i) for i in val])
    return val, [to_tensor(a) for a in (views, rend, conf, truth)]


def _mean_psnr(pred: torch.Tensor, truth: torch.Tensor) -> float:
    return float(
        np.mean([metrics.psnr(p.permute(1, 2, 0).numpy(), t.permute(1, 2, 0).numpy()) for p, t in zip(pred, truth)])
    )


def held_back_fixer(inputs: Scene, small: Scene, base: Renderer, synth: SynthFn, steps: int, seed: int) -> FixerFit:
    """Train and test the fixer on the held-back inputs of ``inputs`` (``small``: the same at the check size;
    ``base``: the fit without the held-back inputs; ``synth``: the network). Needs two held-back photos."""
    val, (v, r, c, t) = _held_back_pairs(inputs, small, base, synth)
    names = tuple(small.frames[i].name for i in val)
    if len(val) < 2:
        rec = FixerCheck(names, _mean_psnr(v, t), _mean_psnr(r, t), float("nan"), False)
        return FixerFit(None, rec)
    loo = []
    for j in range(len(val)):
        rest = [k for k in range(len(val)) if k != j]
        fx = train_fixer(v[rest], r[rest], c[rest], t[rest], steps=steps, seed=seed)
        with torch.no_grad():
            loo.append(blend(fx, v[j : j + 1], r[j : j + 1], c[j : j + 1]))
    p_view, p_render, p_fixed = _mean_psnr(v, t), _mean_psnr(r, t), _mean_psnr(torch.cat(loo), t)
    used = p_fixed > max(p_view, p_render)
    log.info(
        "fixer on %d held-back inputs: views %.2f dB, render %.2f dB, fixed %.2f dB (%s)",
        len(val),
        p_view,
        p_render,
        p_fixed,
        "used" if used else "not used: it does not beat both",
    )
    fixer = train_fixer(v, r, c, t, steps=steps, seed=seed) if used else None
    return FixerFit(fixer, FixerCheck(names, p_view, p_render, p_fixed, used))
