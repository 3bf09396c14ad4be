"""Lens distortion: the pinhole image a distorted camera would have taken, through OpenCV's camera models.

sparself's geometry is pinhole (warps, plane sweeps, splatting), so a capture whose cameras carry distortion
(COLMAP's SIMPLE_RADIAL, OPENCV, fisheye models...) is undistorted once, when it is read. The coefficients
``D`` are OpenCV's: (k1, k2, p1, p2[, k3, k4, k5, k6]) for the perspective models, (k1, k2, k3, k4) for the
fisheye ones (``fisheye=True``); COLMAP's models are these with the missing terms zero.

Pixel convention: COLMAP's, as everywhere in sparself (the centre of the top-left pixel is (0.5, 0.5)); OpenCV
puts it at (0, 0), so matrices and points are shifted by half a pixel on their way in and out.
"""

from __future__ import annotations

import cv2
import numpy as np

_HALF = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])


def _cv(K: np.ndarray) -> np.ndarray:
    return _HALF @ np.asarray(K, np.float64)


def _colmap(K_cv: np.ndarray) -> np.ndarray:
    return np.linalg.inv(_HALF) @ K_cv


def undistort_points(xy: np.ndarray, K: np.ndarray, D: np.ndarray, fisheye: bool, K_new: np.ndarray) -> np.ndarray:
    """Pixel positions in the distorted image -> the same rays' positions in the pinhole image of ``K_new``.

    xy: (M, 2); K, K_new: (3, 3); D: OpenCV coefficients. -> (M, 2) float64.
    """
    pts = np.asarray(xy, np.float64).reshape(-1, 1, 2) - 0.5
    if len(pts) == 0:
        return np.zeros((0, 2))
    D = np.asarray(D, np.float64)
    if fisheye:
        out = cv2.fisheye.undistortPoints(pts, _cv(K), D, R=np.eye(3), P=_cv(K_new))
    else:
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
        out = cv2.undistortPoints(pts, _cv(K), D, R=np.eye(3), P=_cv(K_new), criteria=crit)
    return out.reshape(-1, 2) + 0.5


def _border(w: int, h: int, cx: float, cy: float, n: int = 129) -> np.ndarray:
    """(4 (n + 1), 2) points along the image's outer edge (pixel corners, COLMAP convention), with the
    principal point's row and column, where a radial model bends the edge the most."""
    s = np.linspace(0.0, 1.0, n)
    x, y = np.append(s * w, cx), np.append(s * h, cy)
    zx, zy = np.zeros_like(x), np.zeros_like(y)
    return np.concatenate([np.stack(a, 1) for a in ((x, zx), (x, zx + h), (zy, y), (zy + w, y))])


def distortion_shift(K: np.ndarray, D: np.ndarray, fisheye: bool, size: tuple[int, int]) -> float:
    """The farthest any pixel moves when the image of size (W, H) is undistorted with the same K (pixels):
    how much a pinhole reading of the camera errs. Taken over a grid that includes the edges."""
    w, h = size
    u, v = np.meshgrid(np.linspace(0, w, 17), np.linspace(0, h, 17))
    xy = np.stack([u.ravel(), v.ravel()], 1)
    moved = undistort_points(xy, K, D, fisheye, K)
    return float(np.max(np.linalg.norm(moved - xy, axis=1)))


def pinhole_matrix(K: np.ndarray, D: np.ndarray, fisheye: bool, size: tuple[int, int]) -> np.ndarray:
    """The pinhole K (3, 3) of the undistorted image of the same size (W, H): the same principal point and
    pixel shape, and the widest view whose every pixel the distorted image covers (no blank corners, as
    COLMAP's undistorter makes by default). Fisheye models: OpenCV's estimate of that view (balance 0), whose
    principal point may move by a fraction of a pixel."""
    D = np.asarray(D, np.float64)
    if fisheye:
        K_new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(_cv(K), D, size, np.eye(3), balance=0.0)
        return _colmap(K_new)
    # the edge of the distorted image, undistorted with unit scale: the new image must fit inside it
    w, h = size
    cx, cy = K[0, 2], K[1, 2]
    border = _border(w, h, cx, cy)
    edge = undistort_points(border, K, D, False, np.eye(3))  # normalised image coordinates
    K_new = np.array(K, np.float64)
    left, right = edge[np.isclose(border[:, 0], 0)], edge[np.isclose(border[:, 0], w)]
    top, bottom = edge[np.isclose(border[:, 1], 0)], edge[np.isclose(border[:, 1], h)]
    # normalised extents of the inscribed rectangle, each side kept at its own distance from the axis
    x0, x1 = left[:, 0].max(), right[:, 0].min()
    y0, y1 = top[:, 1].max(), bottom[:, 1].min()
    fx = max(cx / max(-x0, 1e-9), (w - cx) / max(x1, 1e-9))
    fy = max(cy / max(-y0, 1e-9), (h - cy) / max(y1, 1e-9))
    s = max(fx / K[0, 0], fy / K[1, 1])  # one scale: the pixels keep their shape (LLFF stores one focal)
    K_new[0, 0], K_new[1, 1] = s * K[0, 0], s * K[1, 1]
    return K_new


def undistort_image(img: np.ndarray, K: np.ndarray, D: np.ndarray, fisheye: bool, K_new: np.ndarray) -> np.ndarray:
    """(H, W, C) or (H, W) image of the distorted camera -> the pinhole image of ``K_new``, same size
    (bilinear; a pixel whose ray falls off the source repeats its edge)."""
    h, w = img.shape[:2]
    D = np.asarray(D, np.float64)
    if fisheye:
        mx, my = cv2.fisheye.initUndistortRectifyMap(_cv(K), D, np.eye(3), _cv(K_new), (w, h), cv2.CV_32FC1)
    else:
        mx, my = cv2.initUndistortRectifyMap(_cv(K), D, np.eye(3), _cv(K_new), (w, h), cv2.CV_32FC1)
    out = cv2.remap(np.ascontiguousarray(img), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.astype(img.dtype, copy=False)
