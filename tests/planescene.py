"""Test helper: a textured plane Z = depth seen by pinhole cameras, rendered exactly by ray casting.

The texture is an analytic function of world (X, Y), so every image (sources and ground truth) is exact,
with no resampling: a renderer that gets the geometry right differs from it only by its own
interpolation error.
"""

from __future__ import annotations

import numpy as np

from sparself.geometry import Pose, inverse_depth_planes
from sparself.scene import Camera, Frame, Scene

W, H, F = 96, 64, 80.0
NEAR, FAR, NUM_PLANES = 1.0, 10.0, 17
DEPTH = float(inverse_depth_planes(NEAR, FAR, NUM_PLANES)[8])  # exactly the 9th plane, ~1.818


def texture(X: np.ndarray, Y: np.ndarray, seed: int = 0) -> np.ndarray:
    """Smooth colour texture on the plane, periods 10-30 px at DEPTH. (..) -> (.., 3) in [0, 1]."""
    rng = np.random.default_rng(seed)
    out = np.full(X.shape + (3,), 0.5)
    for _ in range(6):
        ang = rng.uniform(0, np.pi)
        period_px = rng.uniform(10, 30)
        k = 2 * np.pi * F / (period_px * DEPTH)  # radians per world unit
        phase = X * np.cos(ang) * k + Y * np.sin(ang) * k + rng.uniform(0, 2 * np.pi)
        out += rng.uniform(0.04, 0.08, size=3) * np.sin(phase)[..., None]
    return np.clip(out, 0.0, 1.0)


def render_plane(pose: Pose, cam: Camera, depth: float = DEPTH, seed: int = 0) -> np.ndarray:
    """Exact image of the plane Z = depth (world) from pose: cast each pixel-centre ray. -> (H, W, 3)."""
    v, u = np.mgrid[0 : cam.height, 0 : cam.width] + 0.5
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1) @ pose.R  # R^T d
    c = pose.center
    s = (depth - c[2]) / rays[..., 2]
    pts = c + s[..., None] * rays
    return texture(pts[..., 0], pts[..., 1], seed).astype(np.float32)


def plane_scene(xs=(0.0, 0.2, 0.4, 0.6), seed: int = 0) -> Scene:
    """Cameras at (x, 0, 0) looking along +z (identity rotation), indices 0..n-1, images in memory."""
    cam = Camera.pinhole(W, H, F)
    frames = []
    for i, x in enumerate(xs):
        pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([x, 0.0, 0.0]))
        frames.append(Frame(f"src{i}", pose, 1, float(i), None, render_plane(pose, cam, seed=seed)))
    return Scene({1: cam}, frames, bounds=(NEAR, FAR))


def seen_by_all(scene: Scene, pose: Pose, margin: float = 2.0) -> np.ndarray:
    """(H, W) bool: the target pixel's plane point projects inside every source, ``margin`` px from the edge."""
    cam = scene.cameras[1]
    v, u = np.mgrid[0 : cam.height, 0 : cam.width] + 0.5
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1) @ pose.R
    c = pose.center
    pts = c + ((DEPTH - c[2]) / rays[..., 2])[..., None] * rays
    ok = np.ones(u.shape, bool)
    for f in scene.frames:
        x = pts @ f.pose.R.T + f.pose.tvec
        p = x @ cam.K.T
        pu, pv = p[..., 0] / p[..., 2], p[..., 1] / p[..., 2]
        ok &= (pu > margin) & (pu < cam.width - margin) & (pv > margin) & (pv < cam.height - margin)
    return ok
