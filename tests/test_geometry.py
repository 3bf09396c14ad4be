"""Geometry written once (sparself.core.geometry), tested against known values and round trips."""

from __future__ import annotations

import numpy as np
import pytest

from sparself.capture.scene import Camera
from sparself.core.geometry import (
    Pose,
    align_similarity,
    at_poses,
    fov_deg,
    interpolate_pose,
    plane_homography,
    quat_angle,
    quat_multiply,
    quat_normalize,
    quat_to_rotmat,
    rotation_angle_deg,
    rotmat_to_quat,
    slerp,
    transform_pose,
)


def axis_angle_quat(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def random_quats(n, seed=0):
    rng = np.random.default_rng(seed)
    return quat_normalize(rng.normal(size=(n, 4)))


def same_rotation(a, b, tol=1e-9):
    return min(np.abs(a - b).max(), np.abs(a + b).max()) < tol


# ---- SLERP -------------------------------------------------------------------------------------


def test_slerp_endpoints():
    for q1, q2 in zip(random_quats(20, 1), random_quats(20, 2)):
        assert same_rotation(slerp(q1, q2, 0.0), q1)
        assert same_rotation(slerp(q1, q2, 1.0), q2)


def test_slerp_unit_norm_for_many_t():
    q1, q2 = random_quats(2, 3)
    for t in np.linspace(-0.5, 1.5, 41):
        assert abs(np.linalg.norm(slerp(q1, q2, t)) - 1.0) < 1e-12


def test_slerp_shortest_arc_q_and_minus_q_same_path():
    q1 = axis_angle_quat([0, 0, 1], 0.0)
    q2 = axis_angle_quat([0, 0, 1], 2.5)  # 143 deg apart
    q2_neg = -q2
    assert np.dot(q1, q2_neg) < 0  # the long way round, if taken naively
    total = quat_angle(q1, q2)
    assert total <= np.pi + 1e-12
    for t in np.linspace(0, 1, 11):
        a, b = slerp(q1, q2, t), slerp(q1, q2_neg, t)
        assert same_rotation(a, b)
        # never longer than the short arc: rotation angle from q1 grows linearly with t up to theta
        assert quat_angle(q1, b) == pytest.approx(t * total, abs=1e-9)


def test_slerp_geodesic_midpoint_equidistant():
    for q1, q2 in zip(random_quats(10, 4), random_quats(10, 5)):
        qm = slerp(q1, q2, 0.5)
        theta = quat_angle(q1, q2)
        assert quat_angle(q1, qm) == pytest.approx(theta / 2, abs=1e-9)
        assert quat_angle(qm, q2) == pytest.approx(theta / 2, abs=1e-9)


def test_slerp_extrapolation_continues_the_arc():
    q1 = axis_angle_quat([1, 2, 3], 0.3)
    step = axis_angle_quat([0, 1, 0], 0.4)
    q2 = quat_multiply(step, q1)
    q = slerp(q1, q2, 1.2)
    assert quat_angle(q1, q) == pytest.approx(1.2 * 0.4, abs=1e-9)
    # same axis: q = step^1.2 * q1
    assert same_rotation(q, quat_multiply(axis_angle_quat([0, 1, 0], 0.48), q1))


def test_slerp_identical_quaternions_no_division_by_zero():
    q = axis_angle_quat([1, 1, 0], 0.7)
    with np.errstate(all="raise"):
        for t in (0.0, 0.5, 1.2):
            out = slerp(q, q, t)
            assert np.all(np.isfinite(out)) and same_rotation(out, q)
        assert same_rotation(slerp(q, -q, 0.5), q)


# ---- rotations and poses ------------------------------------------------------------------------


def test_quaternion_matrix_round_trip():
    for q in random_quats(50, 6):
        R = quat_to_rotmat(q)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
        assert same_rotation(rotmat_to_quat(R), q, tol=1e-9)
    # 180-degree rotations, where naive trace-based conversions break
    for axis in ([1, 0, 0], [0, 1, 0], [1, 1, 0]):
        q = axis_angle_quat(axis, np.pi)
        assert same_rotation(rotmat_to_quat(quat_to_rotmat(q)), q, tol=1e-9)


def test_quat_to_rotmat_of_a_torch_batch_equals_numpy_and_is_differentiable():
    import torch

    qs = random_quats(7, 3) * 2.5  # any norm
    R_np = quat_to_rotmat(qs)
    assert R_np.shape == (7, 3, 3)
    np.testing.assert_allclose(R_np[2], quat_to_rotmat(qs[2]), atol=1e-15)
    q = torch.tensor(qs, requires_grad=True)
    R = quat_to_rotmat(q)
    assert isinstance(R, torch.Tensor) and R.shape == (7, 3, 3)
    np.testing.assert_allclose(R.detach().numpy(), R_np, atol=1e-12)
    R[:, 0, 1].sum().backward()  # the 3DGS fit moves rotations through this gradient
    assert q.grad is not None and torch.isfinite(q.grad).all() and q.grad.abs().sum() > 0


def test_rotation_angle_matches_axis_angle():
    R = quat_to_rotmat(axis_angle_quat([0, 0, 1], np.radians(30)))
    assert rotation_angle_deg(np.eye(3), R) == pytest.approx(30.0)


def test_pose_c2w_w2c_round_trip():
    rng = np.random.default_rng(7)
    for q in random_quats(10, 8):
        p = Pose(q, rng.normal(size=3))
        assert np.allclose(p.c2w() @ p.w2c(), np.eye(4), atol=1e-12)
        p2 = Pose.from_c2w(p.c2w())
        assert np.allclose(p2.w2c(), p.w2c(), atol=1e-12)
        p3 = Pose.from_center(p.qvec, p.center)
        assert np.allclose(p3.tvec, p.tvec, atol=1e-12)
        # the centre projects to the camera origin
        assert np.allclose(p.R @ p.center + p.tvec, 0, atol=1e-12)


def test_pose_rejects_nan():
    with pytest.raises(ValueError):
        Pose([1, 0, 0, 0], [0, np.nan, 0])


def test_interpolate_pose_endpoints_and_straight_line_centres():
    a = Pose.from_center(axis_angle_quat([0, 1, 0], 0.2), [0, 0, 0])
    b = Pose.from_center(axis_angle_quat([0, 1, 0], 0.8), [2, 1, -1])
    assert np.allclose(interpolate_pose(a, b, 0).w2c(), a.w2c(), atol=1e-12)
    assert np.allclose(interpolate_pose(a, b, 1).w2c(), b.w2c(), atol=1e-12)
    for t in (0.25, 0.5, 1.2, -0.2):
        p = interpolate_pose(a, b, t)
        assert np.allclose(p.center, (1 - t) * a.center + t * b.center, atol=1e-12)
        assert quat_angle(a.qvec, p.qvec) == pytest.approx(abs(t) * 0.6, abs=1e-9)


# ---- cameras and homographies -------------------------------------------------------------------


def test_fov_paper_example():
    assert fov_deg(1280, 1536) == pytest.approx(45.24, abs=0.01)
    assert fov_deg(960, 1536) == pytest.approx(34.71, abs=0.01)
    h, v = Camera.pinhole(1280, 960, 1536).fov_deg
    assert (round(h, 2), round(v, 2)) == (45.24, 34.71)


def test_plane_homography_matches_point_projection():
    K_src = np.array([[500.0, 0, 160], [0, 510, 120], [0, 0, 1]])
    K_dst = np.array([[480.0, 0, 150], [0, 480, 110], [0, 0, 1]])
    dst = Pose.from_center(axis_angle_quat([0, 1, 0], 0.1), [0.0, 0.0, 0.0])
    src = Pose.from_center(axis_angle_quat([1, 0, 0], -0.05), [0.3, -0.1, 0.2])
    depth = 4.0
    H = plane_homography(K_src, K_dst, src, dst, depth)
    rng = np.random.default_rng(9)
    for _ in range(10):
        u = np.array([rng.uniform(0, 300), rng.uniform(0, 220), 1.0])
        X_dst = np.linalg.inv(K_dst) @ u * depth  # on the plane z = depth of the dst camera
        X_world = dst.R.T @ (X_dst - dst.tvec)
        x_src = K_src @ (src.R @ X_world + src.tvec)
        p = H @ u
        assert np.allclose(p[:2] / p[2], x_src[:2] / x_src[2], atol=1e-9)


def test_align_similarity_recovers_known_transform():
    rng = np.random.default_rng(10)
    src = rng.normal(size=(30, 3))
    R = quat_to_rotmat(axis_angle_quat([1, -2, 0.5], 1.1))
    s, t = 2.5, np.array([1.0, -3.0, 0.5])
    dst = s * src @ R.T + t
    s2, R2, t2 = align_similarity(src, dst)
    assert s2 == pytest.approx(s) and np.allclose(R2, R, atol=1e-9) and np.allclose(t2, t, atol=1e-9)
    # and a camera moved by it keeps projecting the moved world the same way
    p = Pose.from_center(axis_angle_quat([0, 0, 1], 0.3), [1, 2, 3])
    p2 = transform_pose(p, s2, R2, t2)
    X = np.array([0.5, 0.2, 7.0])
    x1, x2 = p.R @ X + p.tvec, p2.R @ (s * R @ X + t) + p2.tvec
    assert np.allclose(x1[:2] / x1[2], x2[:2] / x2[2], atol=1e-9)


def _at(x: float, turn_deg: float = 0.0) -> Pose:
    """A camera at (x, 0, 0) turned ``turn_deg`` about the y axis."""
    h = np.radians(turn_deg) / 2
    return Pose.from_center(np.array([np.cos(h), 0.0, np.sin(h), 0.0]), np.array([x, 0.0, 0.0]))


def test_at_poses_within_a_quarter_of_the_paths_step():
    path = [_at(x) for x in (0, 2, 4, 6, 8)]  # steps of 2: a target is at a view within 0.5
    targets = [_at(1.0), _at(3.0), _at(5.6), _at(7.0, turn_deg=10.0)]
    views = [_at(1.0), _at(3.4), _at(5.0), _at(7.0)]
    assert at_poses(targets, views, path).tolist() == [True, True, False, False]  # 0, 0.4, 0.6 off; 10 deg turned
    assert at_poses(targets, views, path, within=0.35).tolist() == [True, True, True, False]  # within 0.7
    assert at_poses(targets, views, path, within=0.15).tolist() == [True, False, False, False]  # within 0.3
    assert not at_poses(targets, [], path).any()


def test_at_poses_on_a_path_that_only_turns_is_judged_by_rotation():
    path = [_at(0.0, turn_deg=a) for a in (0, 8, 16, 24)]  # a quarter of the 8-degree turn: 2 degrees
    targets = [_at(0.0, turn_deg=4.0), _at(0.0, turn_deg=13.0)]
    views = [_at(0.0, turn_deg=5.5), _at(0.0, turn_deg=10.0)]
    assert at_poses(targets, views, path).tolist() == [True, False]  # 1.5 and 3 degrees from the nearest view
