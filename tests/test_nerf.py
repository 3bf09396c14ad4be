"""Compact NeRF: fits a textured plane well enough that a held-out view beats the mean colour."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest
import torch

from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.geometry import Pose
from sparself.recon.nerf import NerfConfig, fit, fit_device, pixel_rays, sampling_bounds, scene_normalization

DEPTH = 4.0


def _texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Smooth colour pattern on the plane z = DEPTH, (..., 3) in [0.1, 0.9]."""
    return np.stack(
        [0.5 + 0.4 * np.sin(2.2 * x + 0.3), 0.5 + 0.4 * np.cos(1.7 * y - 0.5), 0.5 + 0.4 * np.sin(1.3 * (x + y))], -1
    ).astype(np.float32)


def _render_plane(pose: Pose, cam: Camera) -> np.ndarray:
    o, d = pixel_rays(pose, cam)
    t = (DEPTH - o[:, 2]) / d[:, 2]
    p = o + t[:, None] * d
    return _texture(p[:, 0], p[:, 1]).reshape(cam.height, cam.width, 3)


def _plane_scene(n_side: int = 3, size: int = 24) -> tuple[Scene, list[Pose]]:
    cam = Camera.pinhole(size, size, fx=size * 0.9)
    frames = []
    for k, (x, y) in enumerate(
        [(x, y) for y in np.linspace(-0.4, 0.4, n_side) for x in np.linspace(-0.4, 0.4, n_side)]
    ):
        pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([x, y, 0.0]))
        frames.append(Frame(f"v{k}", pose, 1, float(k), image=_render_plane(pose, cam)))
    held = [Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([0.2, -0.2, 0.0]))]
    return Scene({1: cam}, frames, bounds=(2.0, 8.0)), held


def test_pixel_rays_follow_colmap_pixel_centres():
    cam = Camera.pinhole(4, 2, fx=2.0, cx=2.0, cy=1.0)
    o, d = pixel_rays(Pose(np.array([1.0, 0, 0, 0]), np.zeros(3)), cam)
    # pixel (row 0, col 0) has its centre at (0.5, 0.5): direction ((0.5 - 2) / 2, (0.5 - 1) / 2, 1)
    np.testing.assert_allclose(d[0], [-0.75, -0.25, 1.0])
    np.testing.assert_allclose(d[-1], [(3.5 - 2) / 2, (1.5 - 1) / 2, 1.0])
    assert np.all(o == 0)


def test_nerf_fits_plane_and_beats_mean_colour_on_held_out_view():
    scene, held = _plane_scene()
    cam = scene.cameras[1]
    t0 = time.process_time()  # CPU time: wall time on a shared machine measures the neighbours
    r = fit(
        scene,
        NerfConfig(
            steps=250, batch_rays=512, n_samples=24, levels=(8, 16, 32), hidden=32, seed=0, progress=False, threads=1
        ),
    )
    img = r.render(held[0], cam)
    elapsed = time.process_time() - t0
    gt = _render_plane(held[0], cam)
    assert img.shape == gt.shape and img.dtype == np.float32
    mse_nerf = float(np.mean((img - gt) ** 2))
    mse_mean = float(np.mean((gt.mean((0, 1)) - gt) ** 2))
    psnr_nerf, psnr_mean = -10 * np.log10(mse_nerf), -10 * np.log10(mse_mean)
    assert psnr_nerf > psnr_mean + 5.0, (psnr_nerf, psnr_mean)
    assert r.history[-1] < r.history[0] / 3
    assert elapsed < 60


def test_nerf_is_deterministic_for_a_seed():
    scene, held = _plane_scene(n_side=2, size=12)
    cfg = dict(steps=20, batch_rays=128, n_samples=8, levels=(8,), hidden=16, progress=False, threads=1)
    a = fit(scene, NerfConfig(seed=3, **cfg)).render(held[0], scene.cameras[1])
    b = fit(scene, NerfConfig(seed=3, **cfg)).render(held[0], scene.cameras[1])
    np.testing.assert_array_equal(a, b)


def test_gsplat_says_clearly_what_it_needs_when_it_cannot_run():
    from sparself.core.errors import SparselfError
    from sparself.recon import gsplat as gs

    ok, why = gs.available()
    if ok:
        pytest.skip("gsplat and CUDA are available here; the clear-error path is not reachable")
    scene, _ = _plane_scene(n_side=2, size=8)
    with pytest.raises(SparselfError, match=r"gsplat reconstructor needs CUDA and `pip install sparself\[gsplat\]`: "):
        gs.fit(scene, steps=1)
    assert why.startswith("gsplat reconstructor needs CUDA")


def test_nerf_rejects_unknown_settings_and_empty_scenes():
    from sparself.core.errors import ConfigError, InputError

    scene, _ = _plane_scene(n_side=2, size=8)
    with pytest.raises(ConfigError, match="stepz"):
        fit(scene, stepz=3)
    with pytest.raises(InputError, match="no frames"):
        fit(scene.subset([]), steps=1)
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="no CUDA device"):
            fit(scene, steps=1, device="cuda")


def test_nerf_fits_on_the_device_it_is_given():
    scene, _ = _plane_scene(n_side=2, size=8)
    r = fit(scene, steps=3, device="cpu", progress=False)
    assert r.field.background.device.type == "cpu"
    assert fit_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")


def _forward_facing_points(background: float, seed: int = 0) -> Scene:
    """3 x 3 cameras at z = 0 looking down +z, sparse points on a near plane (z = 2, 1.2 wide) and on a far
    background (z = ``background``, as wide as the view there), the capture's bounds reaching past both."""
    rng = np.random.default_rng(seed)
    near = np.c_[rng.uniform(-0.6, 0.6, (150, 2)), np.full(150, 2.0)]
    far = np.c_[rng.uniform(-0.5, 0.5, (100, 2)) * background, np.full(100, background)]
    scene, _ = _plane_scene(n_side=3, size=8)
    return replace(scene, points=np.concatenate([near, far]), bounds=(1.0, 1.21 * background))


def test_a_far_background_leaves_the_unit_ball_on_the_near_scene():
    scene = _forward_facing_points(100.0)
    c, r = scene_normalization(scene)
    # the near plane fills the ball: its 1.2-unit width spans a good part of the grid (all the points: r > 40)
    assert np.linalg.norm(c - [0.0, 0.0, 2.0]) < 0.3 and 0.4 < r < 1.0
    # the background only moves the contracted shell: the ball is the same whether it lies at 100 or 1000
    c2, r2 = scene_normalization(_forward_facing_points(1000.0))
    np.testing.assert_allclose(c2, c, atol=1e-9)
    assert r2 == pytest.approx(r)


def test_samples_span_the_sparse_points_not_the_captures_bounds():
    scene = _forward_facing_points(100.0)
    near, far = sampling_bounds(scene)
    # from the points: z from 2 (near plane, seen from the cameras at z = 0) to 100, widened by 10 %
    assert near == pytest.approx(1.8, rel=0.02) and far == pytest.approx(110.0, rel=0.02)
    r = fit(scene, steps=0, levels=(8,), hidden=8, progress=False)
    assert (r.near, r.far) == pytest.approx((near, far))
    # without points the capture's bounds stay the sampling range
    assert sampling_bounds(replace(scene, points=None)) == (1.0, 121.0)


def test_a_scene_without_far_background_keeps_every_point_in_the_ball():
    rng = np.random.default_rng(1)
    scene, _ = _plane_scene(n_side=3, size=8)
    pts = np.c_[rng.uniform(-1, 1, (200, 2)), rng.uniform(2.5, 5.8, 200)]  # depths as llff_bird's
    c, r = scene_normalization(replace(scene, points=pts))
    np.testing.assert_allclose(c, np.median(pts, axis=0))
    assert r == pytest.approx(np.percentile(np.linalg.norm(pts - c, axis=1), 90))
