"""Compact, differentiable 3D Gaussian splatting in plain torch: the CPU path of the "3dgs" reconstructor.

Built for evaluation at <= 128 px with a few thousand Gaussians on 2 CPU cores (minutes a fit), following
the reference 3DGS (Kerbl et al. 2023) and gsplat's conventions so the two paths render the same images:

- projection: world-to-camera (COLMAP), pixel centres at (j + 0.5, i + 0.5); EWA splatting of the 3D
  covariance R S S^T R^T through the perspective Jacobian (its x/z, y/z clamped slightly beyond the field of
  view, as gsplat does), plus a 0.3 px^2 low-pass on the 2D covariance;
- compositing: front to back in camera depth, alpha = min(0.999, opacity * exp(-d^T Sigma^-1 d / 2)),
  alphas under 1/255 skipped, a pixel stops once its transmittance would fall to 1e-4;
- colour: spherical harmonics of degree <= 1 in the direction from the camera centre to the mean, + 0.5,
  clamped at 0;
- fitting: Adam on L1 + 0.2 D-SSIM of one training view a step, initialised from the SfM points (colours
  read from the training views) or random points in the depth bounds, with a clone/split/prune schedule.

:func:`rasterize_reference` composites one Gaussian at a time over the whole image (the plain definition);
:func:`rasterize` does the same at once over the (Gaussian, pixel) pairs whose alpha reaches 1/255, up to where
the pixel turns opaque, with the transmittance as a per-pixel cumulative sum of log(1 - alpha). Tests hold them
equal. A Gaussian's footprint (the bounding box of the ellipse where its alpha can reach 1/255, from its
opacity) drops nothing. Fits run its per-pair work compiled by ``torch.compile`` (:func:`fast`: the same images
to float rounding, the plain path where no compiler runs).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from tqdm.auto import tqdm

from sparself.capture.scene import MIN_POINTS, Camera, Scene
from sparself.core.geometry import Pose, quat_to_rotmat
from sparself.recon.common import ViewOrder

log = logging.getLogger(__name__)

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
ALPHA_MIN, ALPHA_MAX, T_MIN = 1.0 / 255.0, 0.999, 1e-4
EPS2D = 0.3  # px^2 low-pass added to every 2D covariance
NEAR_PLANE = 0.01
EXACT_FLOAT32 = 1 << 24  # whole numbers up to here are exact in float32
EXACT_HALVES_FLOAT32 = 1 << 23  # and whole numbers + 0.5 up to here
INT16_PIXELS = 1 << 15  # images of at most this many pixels number them in int16
BACKEND = "cpu: sparself.recon.splat (plain torch)"


@dataclass
class SplatConfig:
    """Settings of :func:`fit`. Defaults fit llff_bird's 25 views at 128 px in a few minutes on 2 cores.

    steps: optimisation steps (one training view each), at least ``min_steps_per_view`` x views so that a
    denser capture is not fitted less per view (with a fixed count, 35 real views of llff_bird scored
    below 25: 26.44 vs 26.67 dB); init_points: Gaussians to start from (SfM points
    subsampled, or random in the depth bounds); far_reach: how many times further than the sparse points'
    far bound the random ones reach, where the depth bounds come from the points (1: to the bound);
    max_gaussians: growth (clone/split) stops adding beyond this;
    grow_from / grow_until / grow_every: the Gaussians' clone/split schedule (fractions of ``steps`` for the
    first two); grad_threshold: mean screen-space gradient (NDC units, as the reference) that marks a
    Gaussian for cloning (small) or splitting (large: max scale > ``dense_scale`` x scene extent);
    prune_opacity: Gaussians below it are removed at each refinement; view_order: how each step's training
    view is drawn (:func:`~sparself.recon.common.view_order`); sh_degree: 0 or 1, the degree-1
    band switched on at ``sh_from`` x steps; lr_*: Adam learning rates (means: times the scene extent,
    decaying to 1 % by the last step); background: RGB behind every Gaussian.
    """

    steps: int = 1500
    min_steps_per_view: int = 60
    init_points: int = 3000
    # 5 lifted N by 3.9 dB on samples/bird without its bounds file and by 2.9 on dinoSparseRing, but cost
    # templeSparseRing 2.7 dB (docs/results.md): evaluate and densify choose it per capture (evaluation/reach.py)
    far_reach: float = 1.0
    max_gaussians: int = 8000
    grow_from: float = 0.1
    grow_until: float = 0.6
    grow_every: int = 100
    grad_threshold: float = 2e-4
    dense_scale: float = 0.01
    prune_opacity: float = 0.005
    sh_degree: int = 1
    sh_from: float = 0.3
    ssim_lambda: float = 0.2
    lr_means: float = 1.6e-3
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_opacities: float = 5e-2
    lr_sh0: float = 2.5e-3
    lr_sh1: float = 2.5e-3 / 20
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    view_order: ViewOrder = "epochs"
    max_side: int | None = None
    seed: int = 0
    # one thread: its tensors are small (a few 10^5 pairs), so a second thread's barriers cost more than it
    # adds, and on a shared CPU they cost far more (60 steps at 64 px: 12.6 s on 1 thread, 75.9 s on 2)
    threads: int = 1
    # the rasterizer's per-pair work compiled (:func:`fast`; the plain path where no compiler runs): the same
    # images to float rounding, a 64 px step about a quarter cheaper once compiled (seconds, once a process)
    compiled: bool = True
    progress: bool = True

    def __post_init__(self) -> None:
        if self.sh_degree not in (0, 1):
            raise ValueError(f"SplatConfig.sh_degree must be 0 or 1, got {self.sh_degree}")
        if self.steps < 0 or self.init_points < 1 or self.max_gaussians < 1 or self.far_reach < 1:
            raise ValueError(f"invalid SplatConfig {self}")


@dataclass
class Gaussians:
    """N Gaussians: means (N, 3) world; quats (N, 4) wxyz, any norm; log_scales (N, 3); opacity_logits (N,);
    sh (N, K, 3) with K = 1 (degree 0) or 4 (degree 1), colour = SH + 0.5."""

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    opacity_logits: torch.Tensor
    sh: torch.Tensor

    def __len__(self) -> int:
        return int(self.means.shape[0])


@dataclass
class Projected:
    """Gaussians on one image, in depth order, visible ones only: means2d (M, 2) px; conics (M, 3) the
    inverse 2D covariance (a, b, c) of [[a, b], [b, c]]; opacities (M,); colors (M, 3); depths (M,);
    radii (M, 2) px, the half-widths (x, y) of the box where alpha can reach 1/255 (no gradient); ids (M,)
    their rows in the Gaussians."""

    means2d: torch.Tensor
    conics: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    ids: torch.Tensor


def sh_colors(sh: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """RGB of SH coefficients (N, K, 3) seen along unit directions (N, 3): degree 0 or 1, + 0.5, >= 0."""
    c = SH_C0 * sh[:, 0]
    if degree >= 1 and sh.shape[1] >= 4:
        x, y, z = dirs[:, 0:1], dirs[:, 1:2], dirs[:, 2:3]
        c = c + SH_C1 * (-y * sh[:, 1] + z * sh[:, 2] - x * sh[:, 3])
    return (c + 0.5).clamp_min(0.0)


def project(g: Gaussians, w2c: torch.Tensor, K: torch.Tensor, width: int, height: int, sh_degree: int = 1) -> Projected:
    """EWA projection of the Gaussians into one pinhole camera (w2c (4, 4), K (3, 3)), depth sorted."""
    R, t = w2c[:3, :3], w2c[:3, 3]
    pc = g.means @ R.T + t
    x, y, z = pc.unbind(-1)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    M = quat_to_rotmat(g.quats) * torch.exp(g.log_scales)[:, None, :]  # R diag(s)
    cov_c = R @ (M @ M.transpose(1, 2)) @ R.T
    # the Jacobian's x/z, y/z are clamped 30 % of the half field of view beyond the image (gsplat's rule)
    tx, ty = 0.5 * width / fx, 0.5 * height / fy
    zs = z.clamp_min(NEAR_PLANE)
    u = torch.minimum(torch.maximum(x / zs, -(cx / fx + 0.3 * tx)), (width - cx) / fx + 0.3 * tx)
    v = torch.minimum(torch.maximum(y / zs, -(cy / fy + 0.3 * ty)), (height - cy) / fy + 0.3 * ty)
    zero = torch.zeros_like(zs)
    J = torch.stack([fx / zs, zero, -fx * u / zs, zero, fy / zs, -fy * v / zs], -1).view(-1, 2, 3)
    cov2 = J @ cov_c @ J.transpose(1, 2)
    a, b, c = cov2[:, 0, 0] + EPS2D, cov2[:, 0, 1], cov2[:, 1, 1] + EPS2D
    det = a * c - b * b
    means2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], -1)
    opac = torch.sigmoid(g.opacity_logits)
    with torch.no_grad():
        lam = 0.5 * (a + c) + torch.sqrt((0.25 * (a - c) ** 2 + b * b).clamp_min(0.0))
        # alpha >= 1/255 only where d^T Sigma^-1 d <= 2 ln(255 opacity)
        extent = torch.sqrt(2.0 * torch.log((opac / ALPHA_MIN).clamp_min(1.0)))
        radius = extent * torch.sqrt(lam.clamp_min(0.0))
        m2 = means2d.detach()
        # visible as the reference decides it (a square of the largest axis): the growth step counts these
        keep = (
            (z > NEAR_PLANE)
            & (det > 0)
            & (radius > 0)
            & (m2[:, 0] + radius > 0)
            & (m2[:, 0] - radius < width)
            & (m2[:, 1] + radius > 0)
            & (m2[:, 1] - radius < height)
        )
        # that ellipse's bounding box, tighter than the square when it is elongated: the pixels worth visiting
        radii = extent[:, None] * torch.sqrt(torch.stack([a, c], -1).clamp_min(0.0))
        ids = torch.nonzero(keep).squeeze(1)
        ids = ids[torch.argsort(z[ids], stable=True)]
    campos = -R.T @ t
    dirs = torch.nn.functional.normalize(g.means[ids] - campos, dim=-1)
    conics = torch.stack([c[ids], -b[ids], a[ids]], -1) / det[ids, None]
    return Projected(means2d[ids], conics, opac[ids], sh_colors(g.sh[ids], dirs, sh_degree), z[ids], radii[ids], ids)


def _alpha(p_mean, p_conic, p_opac, px, py):
    """alpha of Gaussians at pixel centres (broadcast), 0 where under 1/255 (gsplat's rule)."""
    return _alpha_of(
        (p_mean[..., 0], p_mean[..., 1], p_conic[..., 0], p_conic[..., 1], p_conic[..., 2], p_opac), px, py
    )


def _alpha_of(columns: Sequence[torch.Tensor], px: torch.Tensor, py: torch.Tensor) -> torch.Tensor:
    """:func:`_alpha` from the columns apart: (mx, my, ca, cb, cc, opacity) of the means, conics and opacities."""
    mx, my, ca, cb, cc, opac = columns
    dx, dy = mx - px, my - py
    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
    alpha = (opac * torch.exp(-sigma)).clamp_max(ALPHA_MAX)
    return torch.where((sigma >= 0) & (alpha >= ALPHA_MIN), alpha, torch.zeros_like(alpha))


def _columns_at(
    means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor, at: torch.Tensor
) -> list[torch.Tensor]:
    """[mx, my, ca, cb, cc, opacity], each (P,) at rows ``at`` (P,) of means2d (M, 2), conics (M, 3) and
    opacities (M,), gathered column by column: contiguous columns made a 64 px fit about 12 % faster than
    slices of one (P, k) gather, with the same numbers. index_select, not [at]: its
    backward (index_add) is deterministic on the CPU, accumulate-indexing is not."""
    cols = (means2d[:, 0], means2d[:, 1], conics[:, 0], conics[:, 1], conics[:, 2], opacities)
    return [c.contiguous().index_select(0, at) for c in cols]


def rasterize_reference(
    p: Projected, width: int, height: int, background: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The plain definition: one Gaussian at a time, front to back, over every pixel.

    -> (image (H, W, 3), alpha (H, W))."""
    dt = p.means2d.dtype
    py, px = torch.meshgrid(torch.arange(height, dtype=dt) + 0.5, torch.arange(width, dtype=dt) + 0.5, indexing="ij")
    T = torch.ones(height, width, dtype=dt)
    C = torch.zeros(height, width, 3, dtype=dt)
    done = torch.zeros(height, width, dtype=torch.bool)
    for i in range(len(p.ids)):
        alpha = torch.where(done, torch.zeros_like(T), _alpha(p.means2d[i], p.conics[i], p.opacities[i], px, py))
        nxt = T * (1 - alpha)
        stop = (alpha > 0) & (nxt <= T_MIN)
        use = (alpha > 0) & ~stop
        C = C + torch.where(use, T * alpha, torch.zeros_like(T))[..., None] * p.colors[i]
        T = torch.where(use, nxt, T)
        done = done | stop
    return C + T[..., None] * background, 1 - T


@dataclass
class _Pairs:
    """Every (Gaussian, pixel) with alpha >= 1/255 in front of where the pixel's transmittance falls to T_MIN,
    sorted by pixel and, within a pixel, front to back: gauss (P,) rows of the Projected; pix (P,) = row *
    width + column."""

    gauss: torch.Tensor
    pix: torch.Tensor
    starts: torch.Tensor  # (S,) the first pair of each pixel with any
    first_pix: torch.Tensor  # (S,) those pixels

    @property
    def fields(self) -> tuple[torch.Tensor, ...]:
        """(gauss, pix, starts, first_pix): the tensors :func:`_composite` takes (a compiled function's inputs)."""
        return (self.gauss, self.pix, self.starts, self.first_pix)


def _centres(pix: torch.Tensor, width: int, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """The pixel centres px, py (P,) (column + 0.5, row + 0.5) of pixel indices ``pix`` (P,), by a float
    division (an int64 one made a fit step slower than the two gathers it replaces): exact below
    EXACT_HALVES_FLOAT32 in float32, where index + 0.5 is."""
    f = pix.to(dtype)
    row = torch.floor((f + 0.5) / width)  # the +0.5 keeps the quotient away from whole numbers
    return f - row * width + 0.5, row + 0.5


def _pixel_pairs(p: Projected, width: int, height: int, max_pairs: int = 1 << 26, compiled: bool = False) -> _Pairs:
    """The pairs worth compositing (no gradient: only which pairs exist): each pixel's, front to back, until
    its transmittance falls to T_MIN (:func:`_in_front`: a 64 px dinoSparseRing fit had most of its pairs behind
    that, and dropping them made it a quarter faster; samples/bird's, 3 %). Found with int32 indices and a
    float division for a pixel's column / row in its box: with int64 division and gathers this was half of a
    64 px forward pass. The division is in float64 from EXACT_FLOAT32 pixels on, where float32 is no longer
    exact."""
    with torch.no_grad():
        m, r = p.means2d, p.radii
        if width * height >= EXACT_FLOAT32:
            m, r = m.double(), r.double()
        box = _Boxes.around(m, r, width, height)
        total = int(box.counts.sum())
        if total > max_pairs:
            raise MemoryError(f"3dgs: {total} Gaussian-pixel pairs exceed {max_pairs}")
        gauss, pix, alpha = _front_candidates(m.detach(), p.conics.detach(), p.opacities.detach(), box, compiled)
        # Gaussians are in depth order: a stable sort by pixel keeps it (of int16 keys where they fit: a
        # radix sort, 2.4x faster than of int32 ones; the order is the same)
        key = pix.to(torch.int16) if width * height <= INT16_PIXELS else pix
        pix, sort = torch.sort(key, stable=True)
        pix = pix.long()  # int64 out: the backward of an index_select by int32 indices runs at half the speed
        front = torch.nonzero(_in_front(pix, alpha.index_select(0, sort), width * height)).squeeze(1)
        gauss, pix = gauss.index_select(0, sort.index_select(0, front)).long(), pix.index_select(0, front)
        starts = _starts(pix)
        return _Pairs(gauss, pix, starts, pix.index_select(0, starts))


@dataclass
class _Boxes:
    """The pixel box of each Gaussian (M,): left column x0, top row y0, right column x1, bottom row y1 (float,
    inclusive), nx pixels a row, counts (M,) int32 pixels in all; empty boxes count 0."""

    x0: torch.Tensor
    y0: torch.Tensor
    x1: torch.Tensor
    y1: torch.Tensor
    nx: torch.Tensor
    counts: torch.Tensor
    width: int
    height: int

    @staticmethod
    def around(m: torch.Tensor, r: torch.Tensor, width: int, height: int) -> "_Boxes":
        """The pixel centres (j + 0.5) within half-widths ``r`` (M, 2) of the means ``m`` (M, 2)."""
        x0 = torch.ceil(m[:, 0] - r[:, 0] - 0.5).clamp(0, width - 1)
        x1 = torch.floor(m[:, 0] + r[:, 0] - 0.5).clamp(0, width - 1)
        y0 = torch.ceil(m[:, 1] - r[:, 1] - 0.5).clamp(0, height - 1)
        y1 = torch.floor(m[:, 1] + r[:, 1] - 0.5).clamp(0, height - 1)
        nx, ny = (x1 - x0 + 1).clamp_min(0), (y1 - y0 + 1).clamp_min(0)
        return _Boxes(x0, y0, x1, y1, nx, (nx * ny).int(), width, height)

    def reach(self, open_pixels: torch.Tensor, lo: int, hi: int) -> torch.Tensor:
        """Whether the boxes of Gaussians lo..hi-1 hold any pixel where ``open_pixels`` (H * W,) bool is true
        (hi - lo,): four lookups each in the image's summed-area table."""
        w, h = self.width, self.height
        table = torch.zeros(h + 1, w + 1, dtype=torch.int32)
        table[1:, 1:] = open_pixels.view(h, w).int().cumsum(0).cumsum(1)
        flat = table.view(-1)
        xa, ya = self.x0[lo:hi].long(), self.y0[lo:hi].long() * (w + 1)
        xb, yb = self.x1[lo:hi].long() + 1, (self.y1[lo:hi].long() + 1) * (w + 1)
        return (flat[yb + xb] - flat[ya + xb] - flat[yb + xa] + flat[ya + xa]) > 0


# pairs are found slice by slice of the depth order (at most PAIR_SLICES, of about as many pairs each), and a
# slice's pairs at pixels that the slices in front already took this far (log transmittance) below
# :func:`_in_front`'s line are skipped before the sort: far clear of rounding, so that :func:`_in_front` alone
# decides every pair near its line and the pairs found are the same. On a 64 px dinoSparseRing fit, whose
# pixels are mostly opaque, this made a fit 16 % faster; where few pixels fill up, the slices after the first
# are taken as one (the mean transmittance so far, extrapolated, tells)
PAIR_SLICES, SKIP_MARGIN = 8, 1.0


def _front_candidates(
    means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor, box: _Boxes, compiled: bool
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The (Gaussian, pixel) pairs of the boxes with alpha >= 1/255, less some that lie behind where their
    pixel's transmittance has fallen far below T_MIN (PAIR_SLICES): the Gaussian (P,) int32, the pixel (P,)
    int32 and the alpha (P,), in Gaussian order; the Gaussians' means2d (M, 2), conics (M, 3), opacities (M,)."""
    n_pix, total = box.width * box.height, int(box.counts.sum())
    ends = torch.searchsorted(torch.cumsum(box.counts, 0), torch.arange(1, PAIR_SLICES) * total // PAIR_SLICES)
    bounds = [0, *ends.tolist(), len(box.counts)]
    skip = math.log(T_MIN) - FRONT_MARGIN - SKIP_MARGIN
    log_t = torch.zeros(n_pix, dtype=torch.float64)  # each pixel's log transmittance behind the slices so far
    found: list[tuple[torch.Tensor, ...]] = []
    lo, k = 0, 0
    while k < PAIR_SLICES:
        if found and float(log_t.clamp_min(skip).mean()) * PAIR_SLICES / k > skip:
            k = PAIR_SLICES - 1  # at this rate the mean pixel never fills up: the rest at once
        hi, k = bounds[k + 1], k + 1
        counts = box.counts[lo:hi] * box.reach(log_t > skip, lo, hi) if found else box.counts[lo:hi]
        gauss, pix, alpha = _slice_candidates(means2d, conics, opacities, box, lo, hi, counts, compiled)
        keep = alpha > 0
        if found:
            keep &= log_t.index_select(0, pix.long()) > skip
        keep = torch.nonzero(keep).squeeze(1)
        gauss, pix, alpha = gauss.index_select(0, keep), pix.index_select(0, keep), alpha.index_select(0, keep)
        log_t.index_add_(0, pix.long(), torch.log1p(-alpha).double())
        found.append((gauss, pix, alpha))
        lo = hi
    gauss, pix, alpha = (torch.cat(parts) for parts in zip(*found))
    return gauss, pix, alpha


def _slice_candidates(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    box: _Boxes,
    lo: int,
    hi: int,
    counts: torch.Tensor,
    compiled: bool,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Every pixel of the boxes of Gaussians lo..hi-1, ``counts`` (hi - lo,) int32 of each (0: none): the
    Gaussian (P,) int32 and, by :func:`_candidates`, the pixel (P,) int32 and the alpha (P,)."""
    size = int(counts.sum())
    gauss = torch.repeat_interleave(torch.arange(lo, hi, dtype=torch.int32), counts, output_size=size)
    start = torch.zeros(len(box.counts), dtype=torch.int32)
    start[lo:hi] = torch.cumsum(counts, 0, dtype=torch.int32) - counts
    candidates = fast(_candidates, _probe_candidates) if compiled and size > 1 else _candidates
    pix, alpha = candidates(means2d, conics, opacities, box.x0, box.y0, box.nx, start, gauss, box.width)
    return gauss, pix, alpha


def _starts(pix: torch.Tensor) -> torch.Tensor:
    """The first position (S,) of each run of equal pixels in ``pix`` (P,), sorted by pixel."""
    first = torch.ones_like(pix, dtype=torch.bool)
    first[1:] = pix[1:] != pix[:-1]
    return torch.nonzero(first).squeeze(1)


# a pair is dropped only where its pixel's transmittance is this far (in log) below T_MIN: clear of rounding
# between this pass and the composite's own (compiled code may round its alphas otherwise)
FRONT_MARGIN = 1e-2


def _in_front(pix: torch.Tensor, alpha: torch.Tensor, n_pix: int) -> torch.Tensor:
    """Which of the pairs (P,) bool, sorted by pixel ``pix`` (P,) and front to back, with alphas ``alpha`` (P,),
    a pixel may still composite: those after which its transmittance stays above T_MIN (less FRONT_MARGIN).
    The rest count for nothing in the composite, colour or gradient: dropping them is exact."""
    starts = _starts(pix)
    incl = _pixel_cumsum(torch.log1p(-alpha).double(), pix, starts, pix.index_select(0, starts), n_pix)
    return incl > math.log(T_MIN) - FRONT_MARGIN


def _pixel_cumsum(
    log1m: torch.Tensor, pix: torch.Tensor, starts: torch.Tensor, first_pix: torch.Tensor, n_pix: int
) -> torch.Tensor:
    """Each pair's log transmittance after it (P,): the sum of ``log1m`` (P,) over its pixel's pairs up to it
    and itself, for pairs sorted by pixel ``pix`` (P,) whose runs start at ``starts`` (S,) in pixels
    ``first_pix`` (S,). One cumsum over every pair, less each pixel's sum before its first pair, spread through
    an image (a per-pair segment number would cost a cumsum over every pair)."""
    incl = torch.cumsum(log1m, 0)
    before = torch.zeros(n_pix, dtype=incl.dtype).index_copy(0, first_pix, (incl - log1m).index_select(0, starts))
    return incl - before.index_select(0, pix)


def _candidates(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    x0: torch.Tensor,
    y0: torch.Tensor,
    nx: torch.Tensor,
    start: torch.Tensor,
    gauss: torch.Tensor,
    width: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each pair of a Gaussian ``gauss`` (P,) int32 and a pixel of its box, whose pairs are consecutive from
    ``start`` (M,) int32, row by row from the left column ``x0``, top row ``y0``, ``nx`` (M,) pixels a row:
    the pixel (P,) int32 (row * width + column) and the Gaussian's alpha there (P,), 0 where under 1/255,
    from means2d (M, 2), conics (M, 3) and opacities (M,)."""
    local = (torch.arange(gauss.shape[0], dtype=torch.int32) - start.index_select(0, gauss)).to(x0.dtype)
    nxg = nx.index_select(0, gauss)
    row = torch.floor((local + 0.5) / nxg)  # the +0.5 keeps the quotient away from whole numbers
    px = x0.index_select(0, gauss) + (local - row * nxg) + 0.5
    py = y0.index_select(0, gauss) + row + 0.5
    pix = ((py - 0.5) * width + (px - 0.5)).int()
    return pix, _alpha_of(_columns_at(means2d, conics, opacities, gauss), px, py)


def _composite(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    pairs: tuple[torch.Tensor, ...],
    width: int,
    n_pix: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Front-to-back compositing over the pairs ``(gauss, pix, starts, first_pix)`` of :class:`_Pairs` in an image
    ``width`` pixels wide, with the Gaussians' means2d (M, 2), conics (M, 3), opacities (M,) and colors (M, 3).

    -> (colour (n_pix, 3) before the background, log transmittance (n_pix,))."""
    gauss, pix, starts, first_pix = pairs
    dt = means2d.dtype
    px, py = _centres(pix, width, torch.float64 if n_pix > EXACT_HALVES_FLOAT32 else dt)
    alpha = _alpha_of(_columns_at(means2d, conics, opacities, gauss), px.to(dt), py.to(dt))
    log1m = torch.log1p(-alpha).double()  # transmittance in log space: a segmented cumsum per pixel
    incl = _pixel_cumsum(log1m, pix, starts, first_pix, n_pix)
    use = (incl > math.log(T_MIN)).to(dt)  # a pixel stops before its transmittance falls to 1e-4
    w = alpha * use * torch.exp((incl - log1m).to(dt))
    C = torch.zeros(n_pix, 3, dtype=dt).index_add(0, pix, w[:, None] * colors.index_select(0, gauss))
    return C, torch.zeros(n_pix, dtype=dt).index_add(0, pix, log1m.to(dt) * use)


def rasterize(
    p: Projected, width: int, height: int, background: torch.Tensor, compiled: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """Vectorised compositing over the (Gaussian, pixel) pairs that matter; equal to
    :func:`rasterize_reference`. compiled: the per-pair work by :func:`fast` (equal to float rounding).
    -> (image (H, W, 3), alpha (H, W))."""
    pairs = _pixel_pairs(p, width, height, compiled=compiled)
    composite = fast(_composite, _probe_composite) if compiled and len(pairs.pix) > 1 else _composite
    C, logT = composite(p.means2d, p.conics, p.opacities, p.colors, pairs.fields, width, width * height)
    T = torch.exp(logT)
    return (C + T[:, None] * background).view(height, width, 3), (1 - T).view(height, width)


# ---- the compiled fast path ----------------------------------------------------------------------


_FAST: dict[Callable, Callable | None] = {}
_FAST_LOCK = threading.Lock()


def fast(fn: Callable, probe: Callable[[Callable], object]) -> Callable:
    """``fn`` compiled by ``torch.compile`` (inductor, dynamic shapes), or ``fn`` itself where that fails (no C++
    compiler, an unsupported platform; said once in the log). ``probe(compiled)`` runs it once on small inputs,
    gradients included, so that a failure shows here and not in a fit. Fusing the per-pair elementwise work
    makes a 64 px fit step about a quarter cheaper than the plain path's op-by-op kernels."""
    with _FAST_LOCK:
        if fn not in _FAST:
            try:
                compiled = torch.compile(fn, dynamic=True)
                probe(compiled)
                _FAST[fn] = compiled
            except Exception as e:  # noqa: BLE001 - any compiler failure leaves the plain path, which is exact
                log.warning("3dgs: %s is not compiled (%s); the plain torch path runs", fn.__name__, _first_line(e))
                _FAST[fn] = None
        return _FAST[fn] or fn


def _first_line(e: Exception) -> str:
    return (str(e).strip().splitlines() or [type(e).__name__])[0][:200]


# the probe's sizes are unlike any other (3 colours): a size equal to a constant is compiled as that constant
PROBE_GAUSSIANS, PROBE_SIDES = 7, (6, 5)


def _probe_inputs() -> tuple[Projected, _Pairs]:
    """PROBE_GAUSSIANS float32 Gaussians over an image of PROBE_SIDES, with gradients on their means, conics,
    opacities and colours."""
    n, (w, h) = PROBE_GAUSSIANS, PROBE_SIDES
    gen = torch.Generator().manual_seed(0)
    means2d = (torch.rand(n, 2, generator=gen) * torch.tensor([w, h])).requires_grad_(True)
    conics = torch.tensor([[0.5, 0.1, 0.4]] * n, requires_grad=True)
    opac = torch.full((n,), 0.6, requires_grad=True)
    colors = torch.rand(n, 3, generator=gen).requires_grad_(True)
    radii = torch.full((n, 2), 4.0)
    p = Projected(means2d, conics, opac, colors, torch.ones(n), radii, torch.arange(n))
    return p, _pixel_pairs(p, w, h)


def _probe_composite(compiled: Callable) -> None:
    p, pairs = _probe_inputs()
    C, logT = compiled(
        p.means2d, p.conics, p.opacities, p.colors, pairs.fields, PROBE_SIDES[0], PROBE_SIDES[0] * PROBE_SIDES[1]
    )
    (C.sum() + logT.sum()).backward()


def _probe_candidates(compiled: Callable) -> None:
    p, _ = _probe_inputs()
    n = PROBE_GAUSSIANS
    corner = torch.arange(n, dtype=torch.float32) % 3
    start = torch.arange(0, 4 * n, 4, dtype=torch.int32)
    with torch.no_grad():
        compiled(
            p.means2d.detach(),
            p.conics.detach(),
            p.opacities.detach(),
            corner,
            corner.clone(),  # not the same tensor: the compiled code would assume the two always are
            torch.full((n,), 2.0),
            start,
            torch.arange(n, dtype=torch.int32).repeat_interleave(4).clone(),  # not a view: as in a fit
            PROBE_SIDES[0],
        )


def render_gaussians(
    g: Gaussians,
    pose: Pose,
    camera: Camera,
    background: torch.Tensor,
    sh_degree: int = 1,
    reference: bool = False,
    compiled: bool = False,
) -> tuple[torch.Tensor, Projected]:
    """(H, W, 3) image of the Gaussians (differentiable) and their projection: by :func:`rasterize_reference`,
    or :func:`rasterize` (``compiled``: its fast path)."""
    dt = g.means.dtype
    w2c = torch.as_tensor(pose.w2c(), dtype=dt)
    K = torch.as_tensor(camera.K, dtype=dt)
    p = project(g, w2c, K, camera.width, camera.height, sh_degree)
    if reference:
        img, _ = rasterize_reference(p, camera.width, camera.height, background.to(dt))
    else:
        img, _ = rasterize(p, camera.width, camera.height, background.to(dt), compiled)
    return img, p


# ---- fitting ------------------------------------------------------------------------------------


class SplatRenderer:
    """Fitted Gaussians. ``render(pose, camera) -> (H, W, 3) float32 in [0, 1]``; ``backend`` names the path."""

    backend = BACKEND

    def __init__(self, gaussians: Gaussians, sh_degree: int, background: torch.Tensor, history: list[float]):
        self.gaussians = gaussians
        self.sh_degree = sh_degree
        self.background = background
        self.history = history  # training loss per step

    @torch.no_grad()
    def render(self, pose: Pose, camera: Camera) -> np.ndarray:
        img, _ = render_gaussians(self.gaussians, pose, camera, self.background, self.sh_degree)
        return img.clamp(0, 1).numpy().astype(np.float32)


def _point_colors(scene: Scene, pts: np.ndarray, views: int = 8) -> np.ndarray:
    """(P, 3) colour of each point in the first of up to ``views`` training images that sees it (0.5 else);
    frames of loss weight 0 are not read."""
    cols = np.full((len(pts), 3), 0.5, np.float32)
    todo = np.ones(len(pts), bool)
    counted = [k for k, f in enumerate(scene.frames) if f.weight > 0]
    for j in np.unique(np.linspace(0, len(counted) - 1, min(views, len(counted))).round().astype(int)):
        i = counted[j]
        cam, pose = scene.camera(int(i)), scene.frames[int(i)].pose
        pc = pts @ pose.R.T + pose.tvec
        z = np.maximum(pc[:, 2], 1e-9)
        u = np.floor(cam.fx * pc[:, 0] / z + cam.cx).astype(int)
        v = np.floor(cam.fy * pc[:, 1] / z + cam.cy).astype(int)
        ok = todo & (pc[:, 2] > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        if ok.any():
            cols[ok] = scene.load(int(i))[v[ok], u[ok]]
            todo &= ~ok
    return cols


def init_gaussians(scene: Scene, cfg: SplatConfig, rng: np.random.Generator) -> Gaussians:
    """Gaussians at the SfM points (at most ``init_points``, coloured from the training views), topped up to
    ``init_points`` with random points in the cameras' depth-bounded frusta when there are fewer (all random
    without SfM points); isotropic, scale = mean distance to 3 neighbours."""
    from sparself.recon.common import frustum_points

    pts = np.zeros((0, 3))
    if scene.points is not None and len(scene.points) >= MIN_POINTS:
        pts = np.asarray(scene.points, np.float64)
    if len(pts) > cfg.init_points:
        pts = pts[np.sort(rng.choice(len(pts), cfg.init_points, replace=False))]
    elif len(pts) < cfg.init_points:
        # a few hundred points (triangulated from a sparse capture's inputs) start too few Gaussians to
        # densify from: 616 on llff_bird scored 1.5 dB apart between fit seeds, and 215 on samples/bird
        # 2.3 dB below random points alone
        pts = np.concatenate(
            [pts, frustum_points(scene, cfg.init_points - len(pts), rng, cfg.far_reach).astype(np.float32)]
        )
    cols = _point_colors(scene, pts)
    means = torch.tensor(pts, dtype=torch.float32)
    knn = torch.cat(
        [torch.cdist(c, means).topk(min(4, len(means)), largest=False).values[:, 1:].mean(1) for c in means.split(1024)]
    )  # in chunks: a full distance matrix grows as N^2
    n = len(means)
    sh = torch.zeros(n, 4 if cfg.sh_degree else 1, 3)
    sh[:, 0] = (torch.from_numpy(cols) - 0.5) / SH_C0
    return Gaussians(
        means,
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.log(knn.clamp_min(1e-7))[:, None].repeat(1, 3),
        torch.logit(torch.full((n,), 0.1)),
        sh,
    )


_FIELDS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def _make_optimizer(g: Gaussians, cfg: SplatConfig, extent: float) -> torch.optim.Adam:
    for name in _FIELDS:
        getattr(g, name).requires_grad_(True)
    lrs = {
        "means": cfg.lr_means * extent,
        "quats": cfg.lr_quats,
        "log_scales": cfg.lr_scales,
        "opacity_logits": cfg.lr_opacities,
        "sh": cfg.lr_sh0,
    }
    return torch.optim.Adam([{"params": [getattr(g, k)], "lr": lr, "name": k} for k, lr in lrs.items()], eps=1e-15)


def _replace(g: Gaussians, opt: torch.optim.Adam, keep: torch.Tensor, new: dict[str, torch.Tensor]) -> Gaussians:
    """Keep rows ``keep`` of every parameter and append ``new`` rows; Adam's moments follow their rows
    (zero for the new ones), as in the reference implementation."""
    out = {}
    for group in opt.param_groups:
        name, old = group["name"], group["params"][0]
        add = new[name].detach() if new else old.detach()[:0]
        p = torch.cat([old.detach()[keep], add]).requires_grad_(True)
        st = opt.state.pop(old, None)
        if st:
            for k in ("exp_avg", "exp_avg_sq"):
                st[k] = torch.cat([st[k][keep], torch.zeros_like(add)])
            opt.state[p] = st
        group["params"][0] = p
        out[name] = p
    return Gaussians(**out)


def _grow(g: Gaussians, opt, grads: torch.Tensor, cfg: SplatConfig, extent: float, gen: torch.Generator) -> Gaussians:
    """Clone small high-gradient Gaussians, split large ones in two (scales / 1.6), prune faint ones."""
    with torch.no_grad():
        big = torch.exp(g.log_scales).amax(1) > cfg.dense_scale * extent
        hot = grads > cfg.grad_threshold
        room = cfg.max_gaussians - len(g)
        if int(hot.sum()) > room:  # the hottest first when the budget is short
            hot = torch.zeros_like(hot)
            if room > 0:
                hot[torch.topk(grads, room).indices] = True
        clone, split = hot & ~big, hot & big
        new = {k: torch.cat([getattr(g, k)[clone]] + [getattr(g, k)[split]] * 2) for k in _FIELDS}
        s = torch.exp(g.log_scales[split])
        draws = [torch.randn(s.shape, generator=gen).to(s.device) for _ in range(2)]  # the CPU's stream anywhere
        offs, offs2 = ((quat_to_rotmat(g.quats[split]) @ (s * d)[..., None])[..., 0] for d in draws)
        nc = int(clone.sum())
        new["means"][nc:] = torch.cat([g.means[split] + offs, g.means[split] + offs2])
        new["log_scales"][nc:] = torch.log(torch.cat([s, s]) / 1.6)
        keep = ~split & (torch.sigmoid(g.opacity_logits) >= cfg.prune_opacity)
    return _replace(g, opt, keep, new)


# (Gaussians, pose, camera, background (3,), SH degree) -> (the (H, W, 3) image, with gradients; a callable
# that, after backward, gives the visible Gaussians' rows (M,) and their screen-space mean gradients (M, 2) px,
# or None when the render had none): the one step where the CPU path and gsplat differ
Rasterizer = Callable[
    [Gaussians, Pose, Camera, torch.Tensor, int],
    tuple[torch.Tensor, Callable[[], tuple[torch.Tensor, torch.Tensor] | None]],
]


def cpu_rasterizer(
    g: Gaussians, pose: Pose, camera: Camera, background: torch.Tensor, sh_degree: int, compiled: bool = False
):
    """:data:`Rasterizer` of the plain-torch path (:func:`render_gaussians`; ``compiled``: its fast path)."""
    img, p = render_gaussians(g, pose, camera, background, sh_degree, compiled=compiled)
    p.means2d.retain_grad()
    return img, lambda: None if p.means2d.grad is None else (p.ids, p.means2d.grad)


def fit_config(scene: Scene, config: SplatConfig | None, overrides: dict, what: str) -> tuple[Scene, SplatConfig]:
    """(scene, config) of a fit: :func:`~sparself.recon.common.prepare_fit`, and at least
    ``min_steps_per_view`` steps per training view."""
    from sparself.recon.common import prepare_fit

    scene, cfg = prepare_fit(scene, SplatConfig, config, overrides, what)
    return scene, dataclasses.replace(cfg, steps=max(cfg.steps, cfg.min_steps_per_view * len(scene)))


def fit(scene: Scene, config: SplatConfig | None = None, **overrides) -> SplatRenderer:
    """Fit Gaussians to every frame of ``scene`` on the CPU (images at the cameras' size).

    config: a :class:`SplatConfig`; keyword overrides replace its fields. Deterministic for ``config.seed``.
    """
    from sparself.recon.common import at_most_threads

    scene, cfg = fit_config(scene, config, overrides, "3dgs")
    with at_most_threads(cfg.threads):
        raster = functools.partial(cpu_rasterizer, compiled=cfg.compiled)
        g, history = fit_gaussians(scene, cfg, raster, torch.device("cpu"))
    return SplatRenderer(g, cfg.sh_degree, torch.tensor(cfg.background, dtype=torch.float32), history)


def _on(g: Gaussians, device: torch.device) -> Gaussians:
    return Gaussians(**{k: getattr(g, k).to(device) for k in _FIELDS})


def fit_gaussians(
    scene: Scene, cfg: SplatConfig, raster: Rasterizer, device: torch.device
) -> tuple[Gaussians, list[float]]:
    """The recipe of :class:`SplatConfig` with ``raster`` drawing each step's view on ``device``: the fitted
    Gaussians (detached, on ``device``) and the training loss of each step. Every random draw is made on the
    CPU, so a seed starts and grows the same Gaussians on any device."""
    from sparself.recon.common import photometric_loss, view_order

    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    extent = float(scene.scale())
    g = _on(init_gaussians(scene, cfg, rng), device)
    opt = _make_optimizer(g, cfg, extent)
    images = [torch.from_numpy(scene.load(i)).to(device) for i in range(len(scene))]
    pixel_weights = map(scene.pixel_weight, range(len(scene)))
    weights = [None if w is None else torch.from_numpy(w).to(device) for w in pixel_weights]
    bg = torch.tensor(cfg.background, dtype=torch.float32, device=device)
    decay = 0.01 ** (1.0 / max(cfg.steps, 1))
    acc, cnt = torch.zeros(len(g), device=device), torch.zeros(len(g), device=device)
    d0, d1 = int(cfg.grow_from * cfg.steps), int(cfg.grow_until * cfg.steps)
    history: list[float] = []
    order = view_order(len(scene), cfg.steps, rng, cfg.view_order)
    for step, i in enumerate(tqdm(order, total=cfg.steps, desc="3dgs fit", disable=not cfg.progress, leave=False)):
        cam = scene.camera(i)
        deg = cfg.sh_degree if step >= cfg.sh_from * cfg.steps else 0
        img, screen = raster(g, scene.frames[i].pose, cam, bg, deg)
        loss = photometric_loss(img[None], images[i][None], cfg.ssim_lambda, weights[i])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        opt.param_groups[0]["lr"] *= decay  # means
        history.append(float(loss.detach()))
        seen = screen() if step < d1 else None
        if seen is not None:
            ids, gr = seen
            gr = gr * torch.tensor([cam.width / 2.0, cam.height / 2.0], device=device)  # pixels -> NDC
            acc.index_add_(0, ids, gr.norm(dim=-1))
            cnt.index_add_(0, ids, torch.ones(len(ids), device=device))
        if d0 <= step < d1 and step > 0 and step % cfg.grow_every == 0:
            g = _grow(g, opt, acc / cnt.clamp_min(1), cfg, extent, gen)
            acc, cnt = torch.zeros(len(g), device=device), torch.zeros(len(g), device=device)
    log.info(
        "3dgs (%s): %d Gaussians after %d steps, final loss %.4f",
        device.type,
        len(g),
        cfg.steps,
        history[-1] if history else float("nan"),
    )
    return Gaussians(**{k: getattr(g, k).detach() for k in _FIELDS}), history
