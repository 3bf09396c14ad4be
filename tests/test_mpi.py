"""MPI renderer against a synthetic scene of known depth, plus the registry."""

import numpy as np
import pytest
import torch

from planescene import DEPTH, NUM_PLANES, plane_scene, render_plane, seen_by_all
from sparself.capture.scene import Camera
from sparself.core.errors import ConfigError
from sparself.core.geometry import Pose, plane_homography, rotmat_to_quat
from sparself.core.metrics import psnr
from sparself.recon import RECONSTRUCTORS, Renderer, get_reconstructor
from sparself.recon.mpi import MpiConfig, fit, render_mpi

torch.set_num_threads(2)


@pytest.fixture(scope="module")
def renderer():
    return fit(plane_scene(), MpiConfig(num_planes=NUM_PLANES))


def _rotated_pose():
    a = np.radians(3.0)  # yaw 3 degrees and a little pitch: the MPI planes are no longer fronto-parallel
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    b = np.radians(1.5)
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return Pose.from_center(rotmat_to_quat(Rx @ Ry), np.array([0.3, 0.03, 0.05]))


def test_plane_depth_is_an_mpi_plane(renderer):
    assert np.min(np.abs(renderer.depths - DEPTH)) < 1e-9


def test_new_pose_matches_exact_plane_warp(renderer):
    pose = _rotated_pose()
    cam = renderer.scene.cameras[1]
    gt = render_plane(pose, cam)
    m = seen_by_all(renderer.scene, pose)
    assert m.mean() > 0.5
    out = renderer.render(pose, cam)
    assert out.shape == (64, 96, 3)
    assert psnr(out[m], gt[m]) > 35.0


def test_ground_truth_agrees_with_cv2_homography_warp():
    """The ray-cast ground truth equals the plane homography warp of a source (for an unrotated target)."""
    import cv2

    sc = plane_scene()
    cam = sc.cameras[1]
    pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([0.3, 0.03, 0.0]))
    src = sc.frames[1]
    H = plane_homography(cam.K, cam.K, src.pose, pose, DEPTH)  # target pixel -> source pixel
    S = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])  # pixel-centre convention -> cv2 pixel indices
    Hcv = np.linalg.inv(S) @ H @ S
    warped = cv2.warpPerspective(src.image, Hcv, (cam.width, cam.height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    m = seen_by_all(sc, pose)
    assert psnr(warped[m], render_plane(pose, cam)[m]) > 35.0


def test_source_pose_is_reproduced_and_fully_covered(renderer):
    f = renderer.scene.frames[2]
    cam = renderer.scene.cameras[1]
    col, cov = render_mpi(renderer.mpi(2), f.pose, cam.K, (cam.height, cam.width))
    np.testing.assert_allclose(cov.numpy(), 1.0, atol=1e-5)  # farthest plane opaque: nothing shows through
    assert psnr(renderer.render(f.pose, cam), f.image) > 35.0


def test_other_camera_size_and_config_checks(renderer):
    cam = Camera.pinhole(48, 32, 40.0)
    out = renderer.render(_rotated_pose(), cam)
    assert out.shape == (32, 48, 3) and out.dtype == np.float32 and 0 <= out.min() and out.max() <= 1
    with pytest.raises(ValueError):
        MpiConfig(box=4)


def test_registry():
    assert isinstance(RECONSTRUCTORS["mpi"](plane_scene(xs=(0.0, 0.2)), num_planes=4), Renderer)
    assert get_reconstructor("mpi") is RECONSTRUCTORS["mpi"]
    with pytest.raises(ConfigError, match="known: .*mpi"):
        get_reconstructor("nope")


def test_sweep_neighbours_keep_a_minimum_baseline():
    """min_baseline in units of D z_min / f (here 17 * 1 / 80 = 0.2125): closer cameras only fill up."""
    sc = plane_scene(xs=(0.0, 0.1, 0.2, 0.3, 0.4))
    assert fit(sc, MpiConfig(num_planes=NUM_PLANES))._neighbourhood(0) == [0, 1, 2, 3, 4]
    spaced = fit(sc, MpiConfig(num_planes=NUM_PLANES, min_baseline=1.0, neighbors=2))
    assert spaced._neighbourhood(0) == [0, 3, 4]
    assert fit(sc, MpiConfig(num_planes=NUM_PLANES, min_baseline=1.0))._neighbourhood(0) == [0, 3, 4, 2, 1]
    assert spaced._neighbourhood(2) == [2, 4, 0]  # none is far enough: the farthest of the close ones
    with pytest.raises(ValueError):
        MpiConfig(min_baseline=-1)


def test_sweep_can_skip_synthetic_frames():
    from dataclasses import replace

    sc = plane_scene(xs=(0.0, 0.1, 0.2, 0.3, 0.4))
    sc = replace(sc, frames=[replace(f, synthetic=i in (1, 3)) for i, f in enumerate(sc.frames)])
    assert sorted(fit(sc, MpiConfig(num_planes=NUM_PLANES, neighbors=2))._neighbourhood(2)) == [1, 2, 3]
    real_only = fit(sc, MpiConfig(num_planes=NUM_PLANES, neighbors=2, sweep_synthetic=False))
    assert sorted(real_only._neighbourhood(2)) == [0, 2, 4]
    assert sorted(real_only._neighbourhood(1)) == [0, 1, 2]  # a synthetic view still gets its MPI, from real ones


def _neighbourhood_tensors(sc):
    images = torch.from_numpy(np.stack([f.image for f in sc.frames]).transpose(0, 3, 1, 2).copy()).float()
    Ks = np.stack([sc.camera(i).K for i in range(len(sc))])
    w2cs = np.stack([f.pose.w2c() for f in sc.frames])
    return images, Ks, w2cs


def test_a_sweep_counts_each_view_by_its_pixel_weight():
    """Weights of 1 change nothing; a view of weight 0 leaves the MPI as if it were not in the sweep."""
    from sparself.core.geometry import inverse_depth_planes
    from sparself.recon.mpi import build_mpi

    sc = plane_scene(xs=(0.0, 0.1, 0.2, 0.3, 0.4))
    images, Ks, w2cs = _neighbourhood_tensors(sc)
    depths, cfg, pose = inverse_depth_planes(1.0, 10.0, NUM_PLANES), MpiConfig(num_planes=NUM_PLANES), sc.frames[0].pose
    plain = build_mpi(images, Ks, w2cs, pose, depths, cfg).rgba
    ones = torch.ones(5, 1, *images.shape[2:])
    assert torch.allclose(build_mpi(images, Ks, w2cs, pose, depths, cfg, ones).rgba, plain, atol=1e-6)
    noisy = images.clone()
    noisy[3] = torch.rand(noisy[3].shape, generator=torch.Generator().manual_seed(0))
    keep = [0, 1, 2, 4]
    without = build_mpi(images[keep], Ks[keep], w2cs[keep], pose, depths, cfg).rgba
    muted = ones.clone()
    muted[3] = 0.0
    # columns that every view sees on every plane (the nearest shifts 80 px * 0.4 / 1 = 32 px), box included
    seen = (..., slice(36, None))
    assert torch.allclose(build_mpi(noisy, Ks, w2cs, pose, depths, cfg, muted).rgba[seen], without[seen], atol=1e-6)
    assert (build_mpi(noisy, Ks, w2cs, pose, depths, cfg).rgba[seen] - without[seen]).abs().max() > 0.1


def test_a_synthesized_view_of_low_weight_spoils_its_neighbours_mpis_less():
    """The renderer passes each frame's pixel weight to the sweeps: a wrong view at weight 0.01 barely moves the
    MPI of the view beside it, which re-renders its own photo; unweighted sweeps let it in fully."""
    from dataclasses import replace

    sc = plane_scene(xs=(0.0, 0.1, 0.2, 0.3, 0.4))
    noise = np.random.default_rng(0).random(sc.frames[1].image.shape).astype(np.float32)
    bad = replace(sc.frames[1], image=noise, synthetic=True, weight=0.01)
    sc = replace(sc, frames=[bad if i == 1 else f for i, f in enumerate(sc.frames)])
    cam, photo = sc.camera(0), sc.frames[0].image
    scores = {
        on: psnr(
            fit(sc, MpiConfig(num_planes=NUM_PLANES, weighted_sweeps=on, render_k=1)).render(sc.frames[0].pose, cam),
            photo,
        )
        for on in (True, False)
    }
    assert scores[True] > scores[False] + 3.0
