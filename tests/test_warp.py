"""Warps: a textured plane of known depth, seen from two cameras, must reproject exactly."""

from __future__ import annotations

import numpy as np
import torch

from sparself.core.geometry import Pose, intrinsics_matrix, plane_homography, quat_normalize
from sparself.core.warp import homography_warp, plane_homographies, plane_sweep


def _texture(h, w):
    """A smooth texture as a function of continuous pixel coordinates, so sampling is exact-ish."""
    v, u = np.mgrid[0:h, 0:w] + 0.5
    return np.stack([0.5 + 0.4 * np.sin(u / 3.0), 0.5 + 0.4 * np.cos(v / 4.0), 0.5 + 0.3 * np.sin((u + v) / 5.0)])


def test_identity_homography_is_identity():
    img = torch.rand(1, 3, 9, 13)
    out, valid = homography_warp(img, torch.eye(3, dtype=torch.float64)[None], (9, 13))
    torch.testing.assert_close(out, img, atol=1e-6, rtol=0)
    assert valid.min() == 1


def test_pure_translation_shifts_pixels():
    img = torch.rand(1, 1, 10, 10)
    H = torch.tensor([[1.0, 0, 2.0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64)[None]
    out, valid = homography_warp(img, H, (10, 10))
    torch.testing.assert_close(out[0, 0, :, :8], img[0, 0, :, 2:], atol=1e-6, rtol=0)
    assert valid[0, 0, :, 8:].sum() == 0 and valid[0, 0, :, :8].min() == 1


def test_plane_sweep_reprojects_plane_of_known_depth():
    """Source camera sees a plane at depth 5 whose texture is known in source pixel coordinates;
    warping that plane into a moved camera must equal the analytic texture at the mapped pixels."""
    h, w = 40, 48
    K = intrinsics_matrix(50.0, 50.0, w / 2, h / 2)
    src = Pose(np.array([1.0, 0, 0, 0]), np.zeros(3))
    dst = Pose.from_center(quat_normalize([1.0, 0.0, 0.03, 0.0]), [0.3, 0.05, 0.0])
    depth = 5.0
    tex = torch.tensor(_texture(h, w), dtype=torch.float32)[None]
    # the plane z = 5 in the source camera is, in the destination camera, a tilted plane; use a sweep
    # plane in the destination frame instead: choose the world plane z_dst = depth, expressed through H
    H = plane_homography(K, K, src, dst, depth)
    Kt = torch.tensor(K)
    vol, valid = plane_sweep(
        tex,
        Kt[None],
        torch.tensor(src.w2c())[None],
        Kt,
        torch.tensor(dst.w2c()),
        torch.tensor([2.0, depth, 9.0]),
        (h, w),
    )
    assert vol.shape == (1, 3, 3, h, w) and valid.shape == (1, 3, 1, h, w)
    # expected: for each dst pixel, source coordinate by H, texture evaluated analytically there
    v, u = np.mgrid[0:h, 0:w] + 0.5
    p = H @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    us, vs = p[0] / p[2], p[1] / p[2]
    exp = np.stack([0.5 + 0.4 * np.sin(us / 3.0), 0.5 + 0.4 * np.cos(vs / 4.0), 0.5 + 0.3 * np.sin((us + vs) / 5.0)])
    exp = exp.reshape(3, h, w)
    m = valid[0, 1, 0].numpy().astype(bool)
    # shrink the mask by a pixel: bilinear sampling at the border mixes with zero padding
    m[:2], m[-2:], m[:, :2], m[:, -2:] = False, False, False, False
    assert m.mean() > 0.6
    err = np.abs(vol[0, 1].numpy() - exp)[:, m]
    assert err.max() < 0.02  # bilinear interpolation error of a smooth texture
    # a wrong depth plane does not match
    assert np.abs(vol[0, 0].numpy() - exp)[:, m & valid[0, 0, 0].numpy().astype(bool)].mean() > 0.05


def test_batched_homographies_match_numpy():
    rng = np.random.default_rng(1)
    K = intrinsics_matrix(60.0, 55.0, 20.0, 15.0)
    poses = [Pose.from_center(quat_normalize([1, *rng.normal(0, 0.05, 3)]), rng.normal(0, 0.3, 3)) for _ in range(3)]
    dst = Pose.from_center(quat_normalize([1, 0.02, -0.01, 0.0]), [0.1, 0.0, 0.0])
    depths = np.array([1.5, 3.0, 10.0])
    Hs = plane_homographies(
        torch.tensor(np.stack([K] * 3)),
        torch.tensor(np.stack([p.w2c() for p in poses])),
        torch.tensor(K),
        torch.tensor(dst.w2c()),
        torch.tensor(depths),
    )
    for s, p in enumerate(poses):
        for d, z in enumerate(depths):
            np.testing.assert_allclose(Hs[s, d].numpy(), plane_homography(K, K, p, dst, z), atol=1e-9)


def test_the_row_by_row_sampling_grid_equals_its_plain_definition():
    """The warps' fast grid (a row of H over columns and rows apart) samples where every pixel times every
    homography does: the same coordinates, and the same pixels outside the source or behind its camera."""
    from sparself.core.warp import _sample_grid, _sample_grid_reference

    g = torch.Generator().manual_seed(0)
    H = torch.eye(3).repeat(3, 5, 1, 1) + 0.3 * torch.randn(3, 5, 3, 3, generator=g)
    H[..., :2, 2] += 4.0 * torch.randn(3, 5, 2, generator=g)  # shifts that put part of each warp outside
    H[0, 0, 2] = torch.tensor([0.0, 0.0, -1.0])  # every point behind the source camera
    fast, plain = _sample_grid(H, (13, 17), (11, 19)), _sample_grid_reference(H, (13, 17), (11, 19))
    assert fast.shape == plain.shape == (3, 5, 13, 17, 2)
    out = plain[..., 0] == 2.0
    assert 0.2 < out.float().mean() < 0.9 and out[0, 0].all()
    # the same sums in the same order; only a machine that fuses multiply-adds differently may move the last bit
    torch.testing.assert_close(fast, plain, atol=1e-5, rtol=0)
    # pixel (row 2, column 3) of the warp [1, 2], inside its source, by hand
    x, y, z = H[1, 2] @ torch.tensor([3.5, 2.5, 1.0])
    assert z > 0 and not out[1, 2, 2, 3]
    torch.testing.assert_close(fast[1, 2, 2, 3], torch.stack([2 * x / z / 19 - 1, 2 * y / z / 11 - 1]))
