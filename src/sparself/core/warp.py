"""Image warps: homography warps and plane-sweep volumes over tensors, and optical-flow interpolation of
two images (shared by model, baselines, MPI).

Pixel convention (COLMAP's, used everywhere in sparself): the top-left image corner is (0, 0) and the
centre of pixel (row i, col j) is (j + 0.5, i + 0.5). With ``grid_sample(align_corners=False)`` a
continuous pixel coordinate u maps to the normalised coordinate 2 u / W - 1 exactly.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F


def pixel_grid(h: int, w: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """Homogeneous pixel-centre coordinates. -> (H, W, 3) with [..., :] = (u, v, 1)."""
    v, u = torch.meshgrid(
        torch.arange(h, device=device, dtype=dtype) + 0.5,
        torch.arange(w, device=device, dtype=dtype) + 0.5,
        indexing="ij",
    )
    return torch.stack([u, v, torch.ones_like(u)], dim=-1)


def plane_homographies(
    K_src: torch.Tensor, w2c_src: torch.Tensor, K_dst: torch.Tensor, w2c_dst: torch.Tensor, depths: torch.Tensor
) -> torch.Tensor:
    """Destination-to-source homographies of fronto-parallel planes z = depth in the destination camera.

    K_src: (S, 3, 3), w2c_src: (S, 4, 4); K_dst: (3, 3), w2c_dst: (4, 4); depths: (D,).
    Returns (S, D, 3, 3) H with p_src ~ H p_dst. Same formula as :func:`sparself.core.geometry.plane_homography`.
    """
    rel = w2c_src @ torch.linalg.inv(w2c_dst)  # dst camera -> src camera, (S, 4, 4)
    R = rel[:, :3, :3]
    t = rel[:, :3, 3]
    n = torch.tensor([0.0, 0.0, 1.0], dtype=R.dtype, device=R.device)
    tn = t[:, None, :, None] * n[None, None, None, :] / depths[None, :, None, None]  # (S, D, 3, 3)
    M = R[:, None] + tn
    return K_src[:, None] @ M @ torch.linalg.inv(K_dst)[None, None]


def _sample_grid_reference(H: torch.Tensor, out_hw: tuple[int, int], src_hw: tuple[int, int]) -> torch.Tensor:
    """The plain definition of :func:`_sample_grid`: every destination pixel centre times every homography.

    H: (N, M, 3, 3) destination-to-source. -> (N, M, Hd, Wd, 2) grid_sample coordinates, 2 where the sample
    falls outside the source or behind its camera (zeros padding)."""
    hd, wd = out_hw
    p = pixel_grid(hd, wd, device=H.device, dtype=H.dtype).reshape(1, 1, -1, 3) @ H.transpose(-1, -2)  # (N, M, P, 3)
    return _normalised(p[..., 0], p[..., 1], p[..., 2], src_hw).reshape(*H.shape[:2], hd, wd, 2)


def _sample_grid(H: torch.Tensor, out_hw: tuple[int, int], src_hw: tuple[int, int]) -> torch.Tensor:
    """:func:`_sample_grid_reference`, a row of H at a time over the image's columns and rows apart (u varies
    along a row, v down a column): the same sums in the same order, in about 60 % of the time of the
    (P, 3) x (3, 3) products at 64 x 96 px (``benchmarks/warp_step.py``)."""
    hd, wd = out_hw
    u = torch.arange(wd, device=H.device, dtype=H.dtype) + 0.5
    v = (torch.arange(hd, device=H.device, dtype=H.dtype) + 0.5)[:, None]
    h = H[..., None, None]  # (N, M, 3, 3, 1, 1)
    x, y, z = ((h[:, :, r, 0] * u + h[:, :, r, 1] * v) + h[:, :, r, 2] for r in range(3))  # each (N, M, Hd, Wd)
    return _normalised(x, y, z, src_hw)


def _normalised(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor, src_hw: tuple[int, int]) -> torch.Tensor:
    """Homogeneous source pixels (x, y, z), each (...), as grid_sample coordinates (..., 2); 2 outside."""
    hs, ws = src_hw
    # points behind the source camera (z <= 0) are invalid; keep the division finite
    zsafe = torch.where(z.abs() < 1e-8, 1e-8, z)
    nx, ny = 2.0 * (x / zsafe) / ws - 1.0, 2.0 * (y / zsafe) / hs - 1.0
    outside = ~((nx.abs() <= 1.0) & (ny.abs() <= 1.0) & (z > 0))
    return torch.stack([nx.masked_fill_(outside, 2.0), ny.masked_fill_(outside, 2.0)], dim=-1)


def _warp_many(src: torch.Tensor, H: torch.Tensor, out_hw: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Each source image warped by M homographies at once, without copying the source M times.

    src: (N, C, Hs, Ws); H: (N, M, 3, 3) destination-to-source, applied in src's dtype (float32 keeps the
    sampling error far below a pixel at the sizes used here and halves the cost of float64).
    Returns (warped (N, M, C, Hd, Wd), valid (N, M, 1, Hd, Wd)).
    """
    n, c, hs, ws = src.shape
    m = H.shape[1]
    hd, wd = out_hw
    dtype = src.dtype if src.dtype in (torch.float32, torch.float64) else torch.float32
    norm = _sample_grid(H.to(device=src.device, dtype=dtype), out_hw, (hs, ws))  # (N, M, Hd, Wd, 2)
    inside = norm[..., 0] != 2.0  # in range, a coordinate is at most 1
    # the M warps of one source are stacked along the grid's height: one grid_sample call, no copies
    out = F.grid_sample(
        src, norm.reshape(n, m * hd, wd, 2).to(src.dtype), mode="bilinear", padding_mode="zeros", align_corners=False
    )
    out = out.reshape(n, c, m, hd, wd).transpose(1, 2)
    return out, inside.reshape(n, m, 1, hd, wd).to(src.dtype)


def homography_warp(src: torch.Tensor, H: torch.Tensor, out_hw: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Warp images by destination-to-source homographies with bilinear sampling.

    src: (N, C, Hs, Ws); H: (N, 3, 3) mapping destination pixels to source pixels; out_hw: (Hd, Wd).
    Returns (warped (N, C, Hd, Wd), valid (N, 1, Hd, Wd) in {0, 1}: the sample fell inside the source).
    """
    out, valid = _warp_many(src, H[:, None], out_hw)
    return out[:, 0], valid[:, 0]


def plane_sweep(
    src: torch.Tensor,
    K_src: torch.Tensor | np.ndarray,
    w2c_src: torch.Tensor | np.ndarray,
    K_dst: torch.Tensor | np.ndarray,
    w2c_dst: torch.Tensor | np.ndarray,
    depths: torch.Tensor | np.ndarray,
    out_hw: tuple[int, int],
) -> tuple[torch.Tensor, torch.Tensor]:
    """Plane-sweep volume: every source image warped onto every depth plane of the destination camera.

    src: (S, C, H, W); K_src: (S, 3, 3); w2c_src: (S, 4, 4); K_dst: (3, 3); w2c_dst: (4, 4); depths: (D,)
    (tensors or arrays). Homographies are computed in float64, then applied in src's dtype.
    Returns (volume (S, D, C, Hd, Wd), valid (S, D, 1, Hd, Wd)).
    """

    def f64(x):
        return torch.as_tensor(x, dtype=torch.float64, device=src.device)

    H = plane_homographies(f64(K_src), f64(w2c_src), f64(K_dst), f64(w2c_dst), f64(depths))
    return _warp_many(src, H, out_hw)


# ---- optical flow (OpenCV DIS) -------------------------------------------------------------------


def _dis_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dense flow from a to b (a(x) ~ b(x + F(x))), DIS 'medium' preset on 8-bit gray. -> (H, W, 2)."""
    import cv2

    ga = cv2.cvtColor((a * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    gb = cv2.cvtColor((b * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    # cv2's type stubs lack this function
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)  # type: ignore[attr-defined]
    return dis.calc(ga, gb, None)


def _backward_warp(img: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """out(x) = img(x + flow(x)), bilinear, border replicated. img (H, W, 3), flow (H, W, 2)."""
    import cv2

    h, w = flow.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(img, gx + flow[..., 0], gy + flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def flow_pair(i0: np.ndarray, i1: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Both images warped by optical flow to the intermediate time t: I0(x + F_t0) and I1(x + F_t1), with
    the flows from t approximated as in Super SloMo (see :func:`sparself.synthesis.baselines.flow`).
    i0, i1: (H, W, 3) float32 in [0, 1]; t in [0, 1] (beyond it extrapolates). -> two (H, W, 3)."""
    f01, f10 = _dis_flow(i0, i1), _dis_flow(i1, i0)
    ft0 = -(1 - t) * t * f01 + t * t * f10
    ft1 = (1 - t) ** 2 * f01 - t * (1 - t) * f10
    return _backward_warp(i0, ft0.astype(np.float32)), _backward_warp(i1, ft1.astype(np.float32))
