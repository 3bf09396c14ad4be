"""Pose geometry, written once: quaternions, LERP/SLERP, w2c <-> c2w, field of view, plane homographies.

Conventions (the one convention of the whole package, COLMAP's):
- quaternions are ``[qw, qx, qy, qz]`` (scalar first), unit norm, Hamilton product;
- a pose is world-to-camera: ``x_cam = R @ x_world + t``; the camera looks along +z, x right, y down;
- the camera centre is ``C = -R.T @ t``; ``c2w = [[R.T, C], [0, 1]]``.

All functions are pure numpy over float64 arrays (:func:`quat_to_rotmat` takes torch tensors too); leading batch
dimensions are allowed where noted.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, overload

import numpy as np

if TYPE_CHECKING:
    import torch

_EPS = 1e-12


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s). q: (..., 4) -> (..., 4). Raises ValueError on a zero or non-finite quaternion."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(q)) or np.any(n < _EPS):
        raise ValueError("quaternion is zero or not finite")
    return q / n


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a*b. a, b: (..., 4) -> (..., 4)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion. (..., 4) -> (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


@overload
def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor: ...
@overload
def quat_to_rotmat(q: np.ndarray) -> np.ndarray: ...
def quat_to_rotmat(q):
    """Rotation matrix of a (not necessarily unit) quaternion. q: (..., 4) -> (..., 3, 3). A torch tensor
    gives a tensor, differentiable in q (the CPU 3DGS fits the Gaussians' rotations through it)."""
    torch = sys.modules.get("torch")  # a tensor means torch is imported; never import it for numpy
    if torch is not None and isinstance(q, torch.Tensor):
        w, x, y, z = torch.nn.functional.normalize(q, dim=-1).unbind(-1)
        return torch.stack(_rotmat_entries(w, x, y, z), -1).view(*q.shape[:-1], 3, 3)
    w, x, y, z = np.moveaxis(quat_normalize(q), -1, 0)
    return np.stack(_rotmat_entries(w, x, y, z), -1).reshape(np.shape(w) + (3, 3))


def _rotmat_entries(w, x, y, z) -> list:
    """The nine entries, row by row, of the rotation matrix of unit quaternion (w, x, y, z)."""
    return [
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    ]


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion with qw >= 0 of rotation matrix R: (3, 3) -> (4,).

    Uses the eigenvector method (as COLMAP does), robust for all angles including 180 degrees.
    """
    R = np.asarray(R, dtype=np.float64)
    if R.ndim > 2:
        return np.stack([rotmat_to_quat(r) for r in R.reshape(-1, 3, 3)]).reshape(R.shape[:-2] + (4,))
    Rxx, Ryx, Rzx, Rxy, Ryy, Rzy, Rxz, Ryz, Rzz = R.flat
    K = (
        np.array(
            [
                [Rxx - Ryy - Rzz, 0, 0, 0],
                [Ryx + Rxy, Ryy - Rxx - Rzz, 0, 0],
                [Rzx + Rxz, Rzy + Ryz, Rzz - Rxx - Ryy, 0],
                [Ryz - Rzy, Rzx - Rxz, Rxy - Ryx, Rxx + Ryy + Rzz],
            ]
        )
        / 3.0
    )
    vals, vecs = np.linalg.eigh(K)
    q = vecs[[3, 0, 1, 2], np.argmax(vals)]
    if q[0] < 0:
        q = -q
    return q / np.linalg.norm(q)


def quat_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle in radians between the rotations of unit quaternions a and b. (..., 4) -> (...)."""
    d = np.abs(np.sum(quat_normalize(a) * quat_normalize(b), axis=-1))
    return 2.0 * np.arccos(np.clip(d, -1.0, 1.0))


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Geodesic angle in degrees between rotation matrices. (..., 3, 3) -> (...)."""
    Rrel = np.swapaxes(Ra, -1, -2) @ Rb
    cos = (np.trace(Rrel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def lerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """(1 - t) a + t b; t outside [0, 1] extrapolates along the line. a, b: (..., D)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return (1.0 - t) * a + t * b


def slerp(q1: np.ndarray, q2: np.ndarray, t: float) -> np.ndarray:
    """Spherical linear interpolation on the shortest arc. q1, q2: (4,) -> (4,) unit.

    When q1 . q2 < 0 the sign of q2 is flipped (q and -q are the same rotation), so the path is the
    short one. t outside [0, 1] extrapolates along the same great circle (the paper's t = 1.2).
    Nearly identical rotations fall back to normalised LERP, so equal poses never divide by zero.
    """
    q1 = quat_normalize(q1)
    q2 = quat_normalize(q2)
    dot = float(np.dot(q1, q2))
    if dot < 0.0:
        q2, dot = -q2, -dot
    dot = min(dot, 1.0)
    theta = np.arccos(dot)
    if theta < 1e-6:
        return quat_normalize(lerp(q1, q2, t))
    s = np.sin(theta)
    return quat_normalize((np.sin((1.0 - t) * theta) / s) * q1 + (np.sin(t * theta) / s) * q2)


@dataclass(frozen=True)
class Pose:
    """A world-to-camera rigid transform in COLMAP's convention: ``x_cam = R(qvec) x_world + tvec``.

    qvec: (4,) unit quaternion ``[qw, qx, qy, qz]``; tvec: (3,).
    """

    qvec: np.ndarray
    tvec: np.ndarray

    def __post_init__(self) -> None:
        q = np.asarray(self.qvec, dtype=np.float64).reshape(4)
        t = np.asarray(self.tvec, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
            raise ValueError("pose contains NaN or inf")
        object.__setattr__(self, "qvec", quat_normalize(q))
        object.__setattr__(self, "tvec", t)

    @property
    def R(self) -> np.ndarray:
        """World-to-camera rotation, (3, 3)."""
        return quat_to_rotmat(self.qvec)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, (3,)."""
        return -self.R.T @ self.tvec

    def w2c(self) -> np.ndarray:
        """(4, 4) world-to-camera matrix."""
        M = np.eye(4)
        M[:3, :3] = self.R
        M[:3, 3] = self.tvec
        return M

    def c2w(self) -> np.ndarray:
        """(4, 4) camera-to-world matrix (OpenCV camera axes: x right, y down, z forward)."""
        return w2c_to_c2w(self.w2c())

    @classmethod
    def from_w2c(cls, M: np.ndarray) -> "Pose":
        """From a (3, 4) or (4, 4) world-to-camera matrix."""
        M = np.asarray(M, dtype=np.float64)
        return cls(rotmat_to_quat(M[:3, :3]), M[:3, 3])

    @classmethod
    def from_c2w(cls, M: np.ndarray) -> "Pose":
        """From a (3, 4) or (4, 4) camera-to-world matrix in OpenCV camera axes."""
        M = np.asarray(M, dtype=np.float64)
        R = M[:3, :3].T
        return cls(rotmat_to_quat(R), -R @ M[:3, 3])

    @classmethod
    def from_center(cls, qvec: np.ndarray, center: np.ndarray) -> "Pose":
        """From a world-to-camera rotation quaternion and a camera centre."""
        q = quat_normalize(qvec)
        return cls(q, -quat_to_rotmat(q) @ np.asarray(center, dtype=np.float64))

    def as_vector(self) -> np.ndarray:
        """``[tx, ty, tz, qw, qx, qy, qz]`` (the paper's 7-vector, world-to-camera), (7,)."""
        return np.concatenate([self.tvec, self.qvec])


def w2c_to_c2w(M: np.ndarray) -> np.ndarray:
    """Invert rigid transform(s). (..., 4, 4) -> (..., 4, 4); also (..., 3, 4) -> (..., 4, 4)."""
    M = np.asarray(M, dtype=np.float64)
    R = M[..., :3, :3]
    t = M[..., :3, 3]
    out = np.zeros(M.shape[:-2] + (4, 4))
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


c2w_to_w2c = w2c_to_c2w  # the inverse of a rigid transform is the same formula


def interpolate_pose(a: Pose, b: Pose, t: float) -> Pose:
    """Pose at parameter t between a (t=0) and b (t=1); t > 1 extrapolates (the paper uses 1.2).

    The camera *centre* is LERPed (a straight line in world space) and the rotation is SLERPed on the
    shortest arc. LERPing COLMAP's tvec instead would bend the path, since tvec = -R C depends on R.
    """
    q = slerp(a.qvec, b.qvec, t)
    return Pose.from_center(q, lerp(a.center, b.center, t))


def fov_deg(size_px: float, focal_px: float) -> float:
    """Field of view in degrees, 2 atan(size / 2f). The paper: 1280 px, f = 1536 -> 45.24 deg."""
    return float(np.degrees(2.0 * np.arctan(size_px / (2.0 * focal_px))))


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(3, 3) pinhole matrix K."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def relative_pose(src: Pose, dst: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Rigid transform from src camera coordinates to dst camera coordinates: x_dst = R x_src + t."""
    R = dst.R @ src.R.T
    t = dst.tvec - R @ src.tvec
    return R, t


def plane_homography(K_src: np.ndarray, K_dst: np.ndarray, src: Pose, dst: Pose, depth: float) -> np.ndarray:
    """Homography mapping destination pixels to source pixels for the fronto-parallel plane z = depth
    in the destination camera (the plane-sweep / MPI warp).

    For a point X_d on the plane n^T X_d = depth, n = (0, 0, 1): X_s = R X_d + t = (R + t n^T / depth) X_d,
    with (R, t) taking dst camera coordinates to src camera coordinates. Returns (3, 3) H such that
    ``p_src ~ H @ p_dst`` in homogeneous pixel coordinates.
    """
    R, t = relative_pose(dst, src)
    n = np.array([0.0, 0.0, 1.0])
    return K_src @ (R + np.outer(t, n) / depth) @ np.linalg.inv(K_dst)


def inverse_depth_planes(near: float, far: float, n: int) -> np.ndarray:
    """n depths uniform in disparity from near to far (LLFF's MPI planes), near first. -> (n,)."""
    if not (0 < near < far):
        raise ValueError(f"need 0 < near < far, got near={near}, far={far}")
    return 1.0 / np.linspace(1.0 / near, 1.0 / far, n)


def align_similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama similarity (s, R, t) minimising ||dst - (s R src + t)||. src, dst: (N, 3), N >= 3."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var_s = (xs**2).sum() / len(src)
    s = float(np.trace(np.diag(S) @ D) / var_s) if var_s > 0 else 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t


def transform_pose(pose: Pose, s: float, R: np.ndarray, t: np.ndarray) -> Pose:
    """Apply the world similarity X' = s R X + t to a camera: its centre moves, its view rotates."""
    return Pose.from_center(rotmat_to_quat(pose.R @ R.T), s * R @ pose.center + t)


def nearest_point_to_axes(centers: np.ndarray, axes: np.ndarray, max_cond: float = 1e6) -> np.ndarray | None:
    """Least-squares point closest to the lines ``centers[i] + s axes[i]`` (unit axes), e.g. the point
    that the cameras of a ring capture look at. centers, axes: (N, 3). None when the lines are (nearly)
    parallel (condition number above ``max_cond``)."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for o, d in zip(np.asarray(centers, np.float64), np.asarray(axes, np.float64)):
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ o
    if np.linalg.cond(A) >= max_cond:
        return None
    return np.linalg.solve(A, b)


def path_steps(path: list[Pose]) -> tuple[np.ndarray, np.ndarray]:
    """Between consecutive poses of ``path``: the distances of their camera centres and their rotations in
    degrees, each (N - 1,); empty for fewer than two poses."""
    if len(path) < 2:
        return np.zeros(0), np.zeros(0)
    centres, q = np.array([p.center for p in path]), np.stack([p.qvec for p in path])
    return np.linalg.norm(np.diff(centres, axis=0), axis=1), np.degrees(quat_angle(q[:-1], q[1:]))


def at_poses(targets: list[Pose], views: list[Pose], path: list[Pose], within: float = 0.25) -> np.ndarray:
    """Whether each of ``targets`` lies at the pose of one of ``views``: its camera centre within ``within`` x the
    median step between consecutive ``path`` poses (a capture in order) of that view's, and its rotation within
    ``within`` x the path's median turn (at least 1 degree) of that view's. (T,) bool; all False without views.

    A path that only turns (zero median step) is judged by rotation alone, one that only moves by centre alone.
    """
    out = np.zeros(len(targets), dtype=bool)
    if not views or not targets:
        return out
    dists, turns = path_steps(path)
    step = float(np.median(dists)) if len(dists) else 0.0
    turn = float(np.median(turns)) if len(turns) else 0.0
    c_views, q_views = np.array([v.center for v in views]), np.array([v.qvec for v in views])
    for k, t in enumerate(targets):
        near = np.degrees(quat_angle(q_views, t.qvec[None])) <= max(within * turn, 1.0)
        if step > _EPS:
            near &= np.linalg.norm(c_views - t.center, axis=1) <= within * step
        out[k] = bool(near.any())
    return out
