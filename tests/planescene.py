"""Test helper: THE synthetic-scene builder (shared through ``conftest.py``), and the exact renders it uses.

Every synthetic scene is :func:`camera_line`: pinhole cameras on the x axis looking down +z, indices
0..n-1, images in memory, made by an ``image(pose, camera, i)`` function. Two image makers:

- :func:`plane_image`: a textured plane Z = depth, rendered exactly by ray casting. The texture is an
  analytic function of world (X, Y), so every image (sources and ground truth) is exact, with no
  resampling: a renderer that gets the geometry right differs from it only by its own interpolation error.
- :func:`noise_image`: i.i.d. random pixels per frame (for tests of files, names and errors, not geometry).

Presets: :func:`plane_scene` (96 x 64, the geometry tests), :func:`small_plane_scene` (40 x 28, the
network tests), :func:`noise_scene` (32 x 24, the bad-input and robustness tests).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.geometry import Pose, inverse_depth_planes

W, H, F = 96, 64, 80.0
NEAR, FAR, NUM_PLANES = 1.0, 10.0, 17
DEPTH = float(inverse_depth_planes(NEAR, FAR, NUM_PLANES)[8])  # exactly the 9th plane, ~1.818

ImageFn = Callable[[Pose, Camera, int], np.ndarray]


def camera_line(
    xs,
    size: tuple[int, int],
    focal: float,
    image: ImageFn,
    bounds=(NEAR, FAR),
    name: Callable[[int], str] = "src{}".format,
) -> Scene:
    """Cameras at (x, 0, 0) for x in ``xs``, identity rotation (looking along +z), one shared camera of
    ``size`` (W, H) and focal length ``focal``, frame i named ``name(i)`` with index i."""
    cam = Camera.pinhole(size[0], size[1], focal)
    frames = []
    for i, x in enumerate(xs):
        pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([float(x), 0.0, 0.0]))
        frames.append(Frame(name(i), pose, 1, float(i), None, image(pose, cam, i)))
    return Scene({1: cam}, frames, bounds=bounds)


def on_disk(scene: Scene, folder) -> Scene:
    """The scene's in-memory images written to ``folder/images/<name>`` and read from there (``path`` set,
    ``image`` dropped): photos on disk, as a reader would give them."""
    from pathlib import Path

    from sparself.capture.images import save_image

    (Path(folder) / "images").mkdir(parents=True)
    for f in scene.frames:
        f.path = Path(folder) / "images" / f.name
        save_image(f.path, f.image)
        f.image = None
    return scene


# ---- textured plane ---------------------------------------------------------------------------------


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


def waves(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """A cheaper texture with a few long periods (the network tests' small images)."""
    return np.stack(
        [
            0.5 + 0.3 * np.sin(9 * X + 2 * Y),
            0.5 + 0.3 * np.cos(7 * Y - 3 * X),
            0.5 + 0.2 * np.sin(5 * X) * np.cos(6 * Y),
        ],
        -1,
    )


def render_plane(pose: Pose, cam: Camera, depth: float = DEPTH, seed: int = 0, tex=None) -> np.ndarray:
    """Exact image of the plane Z = depth (world) from pose: cast each pixel-centre ray. -> (H, W, 3).
    tex: texture function of world (X, Y) (default :func:`texture` with ``seed``)."""
    v, u = np.mgrid[0 : cam.height, 0 : cam.width] + 0.5
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1) @ pose.R  # R^T d
    c = pose.center
    s = (depth - c[2]) / rays[..., 2]
    pts = c + s[..., None] * rays
    tex = tex or (lambda X, Y: texture(X, Y, seed))
    return tex(pts[..., 0], pts[..., 1]).astype(np.float32)


def plane_image(depth: float = DEPTH, seed: int = 0, tex=None) -> ImageFn:
    return lambda pose, cam, i: render_plane(pose, cam, depth, seed, tex)


def plane_scene(xs=(0.0, 0.2, 0.4, 0.6), seed: int = 0) -> Scene:
    """96 x 64 views of the plane at DEPTH (one of the NUM_PLANES sweep planes over NEAR..FAR)."""
    return camera_line(xs, (W, H), F, plane_image(seed=seed))


# the network tests' scene: small images, a plane at depth 2 and known bounds (1, 4)
SW, SH, SF, SDEPTH = 40, 28, 36.0, 2.0


def small_view(cx: float) -> np.ndarray:
    """The small plane scene's image from a camera at (cx, 0, 0). -> (SH, SW, 3)."""
    pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([cx, 0.0, 0.0]))
    return render_plane(pose, Camera.pinhole(SW, SH, SF), SDEPTH, tex=waves)


def small_plane_scene(n: int = 7, step: float = 0.08) -> Scene:
    return camera_line(
        [i * step for i in range(n)],
        (SW, SH),
        SF,
        plane_image(SDEPTH, tex=waves),
        bounds=(1.0, 4.0),
        name="f{:02d}.png".format,
    )


# ---- random pixels ----------------------------------------------------------------------------------

NW, NH, NF = 32, 24, 28.0


def noise(h: int, w: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).random((h, w, 3)).astype(np.float32)


def noise_scene(
    n: int = 6, size: tuple[int, int] = (NW, NH), same: tuple[int, ...] = (), ext: str = ".png", seed: int = 0
) -> Scene:
    """n views of random pixels named 00.png..; frames in ``same`` repeat the pose of the frame before
    them (identical consecutive poses)."""
    xs, x = [], 0.0
    for i in range(n):
        x = x if i in same else 0.1 * i
        xs.append(x)
    return camera_line(
        xs,
        size,
        NF * size[0] / NW,
        lambda pose, cam, i: noise(size[1], size[0], seed + i),
        bounds=(1.0, 5.0),
        name=lambda i: f"{i:02d}{ext}",
    )


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
