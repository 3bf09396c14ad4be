"""What the reconstructors share and no one of them owns: a fit's settings and scene (:func:`prepare_fit`),
its thread budget, the 3DGS photometric loss and random points in the cameras' frusta (both 3DGS paths)."""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from typing import Literal

import numpy as np
import torch

from sparself.capture.scene import Scene, points_depth_range
from sparself.core.errors import ConfigError, InputError


def prepare_fit(scene: Scene, config_cls, config, overrides: dict, what: str):
    """(scene, config) for a reconstructor's ``fit``: keyword overrides replace config fields (unknown
    ones raise ConfigError), an empty scene raises InputError, ``max_side`` resizes the scene."""
    cfg = config or config_cls()
    unknown = sorted(set(overrides) - set(cfg.__dict__))
    if unknown:
        raise ConfigError(f"{what}: unknown setting(s) {', '.join(unknown)}")
    if overrides:
        cfg = dataclasses.replace(cfg, **overrides)
    if len(scene) == 0:
        raise InputError(f"{what}: the scene has no frames to train on")
    if cfg.max_side:
        scene = scene.resized(cfg.max_side)
    return scene, cfg


@contextlib.contextmanager
def at_most_threads(n: int):
    """torch uses at most n threads (and at least 1) inside; the previous count is restored after."""
    prev = torch.get_num_threads()
    torch.set_num_threads(max(1, min(n, prev)))
    try:
        yield
    finally:
        torch.set_num_threads(prev)


def start_depths(scene: Scene, far_reach: float = 1.0) -> tuple[float, float]:
    """(near, far) depth range of random starting points: the scene's depth bounds, the far one ``far_reach``
    times further when they come from its sparse points (a sparse capture rarely triangulates its background:
    the points' 99th percentile can leave it without Gaussians); bounds from the files are kept as they are."""
    seen = None if scene.bounds is not None or scene.points is None else points_depth_range(scene.points, scene.poses)
    if seen is None:  # bounds from the files, or the camera-layout guess
        return scene.depth_bounds()
    return seen[0], seen[1] * far_reach


def frustum_points(scene: Scene, n: int, rng: np.random.Generator, far_reach: float = 1.0) -> np.ndarray:
    """(about n, 3) random world points: n / len(scene) per camera (at least 1), uniform over its image
    and log-uniform in depth over :func:`start_depths`."""
    near, far = start_depths(scene, far_reach)
    pts = []
    per = max(1, n // max(len(scene), 1))
    for i, f in enumerate(scene.frames):
        cam = scene.camera(i)
        u = rng.uniform(0, cam.width, per)
        v = rng.uniform(0, cam.height, per)
        z = np.exp(rng.uniform(np.log(near), np.log(far), per))
        pc = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], 1)
        pts.append((pc - f.pose.tvec) @ f.pose.R)  # R^T (x - t)
    return np.concatenate(pts)


ViewOrder = Literal["epochs", "uniform"]


def view_order(n: int, steps: int, rng: np.random.Generator, order: ViewOrder = "epochs") -> Iterator[int]:
    """The training view of each of ``steps`` steps over ``n`` views. "epochs": every view once per epoch,
    in a fresh random order each epoch (the reference 3DGS's rule), so no view is seen more than once more
    than another; "uniform": each step's view drawn independently (over a short fit some views are seen
    three times as often as others)."""
    if order == "uniform":
        for _ in range(steps):
            yield int(rng.integers(n))
        return
    epoch: list[int] = []
    for _ in range(steps):
        if not epoch:
            epoch = [int(i) for i in rng.permutation(n)]
        yield epoch.pop()


def photometric_loss(render, gt, ssim_lambda: float, weight=None):
    """The 3DGS loss (1 - lambda) L1 + lambda (1 - SSIM) of (B, H, W, 3) images (kornia's SSIM map, 11-tap
    Gaussian window, borders reflected). weight: per-pixel loss weights (H, W) (a frame's weight x its
    confidence, :meth:`Scene.pixel_weight`) or None (all 1: the plain loss). Weighted, each term is the mean
    over pixels of weight x the pixel's error, so a frame of weight w counts w times a real one and a pixel
    of weight 0 has no gradient."""
    from kornia.metrics import ssim

    dssim = 1 - ssim(render.permute(0, 3, 1, 2), gt.permute(0, 3, 1, 2), 11)  # (B, 3, H, W)
    if weight is None:
        return (1 - ssim_lambda) * (render - gt).abs().mean() + ssim_lambda * dssim.mean()
    l1 = (weight[None, :, :, None] * (render - gt).abs()).mean()
    return (1 - ssim_lambda) * l1 + ssim_lambda * (weight[None, None] * dssim).mean()
