"""LLFF-style multi-plane image (MPI) renderer without learned weights (paper section 3.5, LLFF [11]).

One MPI per source view ("reference"): D fronto-parallel planes in the reference camera, uniform in
disparity between the scene's near and far bounds (:func:`sparself.core.geometry.inverse_depth_planes`).
Where LLFF predicts each plane's RGBA with a network, we derive it from the plane-sweep volume of the
reference's 5-view neighbourhood (the reference + its ``neighbors`` nearest cameras by centre distance):

- cost c_d(p): unbiased variance of the valid warped views at plane d (mean over RGB), box-filtered;
  planes seen by fewer than two views carry no evidence (cost set to the pixel's highest cost); a
  neighbour with per-pixel weights (a synthesized one: its weight x confidence) counts by them in the
  variance (reliability weights) and in the plane colour, as a fit's loss counts its pixels (with
  ``weighted_sweeps``; the reference counts fully in its own MPI, which the blend weighs by its weights);
- depth probability p_d = softmax_d(-c~_d / temperature) with c~ = (c - min_d c) / (mean_d c - min_d c + eps),
  a soft-argmin that is scale free: a pixel whose cost has one clear minimum puts almost all mass on it,
  an untextured pixel (flat cost) spreads it;
- plane colour C_d = (weighted) mean of the valid warped views at plane d;
- alpha α_d such that front-to-back "over" compositing of the planes in the reference view gives the
  weights p_d exactly: α_d = p_d / (1 - Σ_{j<d} p_j), farthest plane opaque.

Rendering a pose: the ``render_k`` MPIs with the nearest camera centres are homography-warped plane by
plane into the target camera and over-composited, giving premultiplied colour C_k and coverage A_k; they
are fused as C = Σ w_k C_k / Σ w_k A_k with w_k = exp(-γ ||t_target - t_k||) (camera centres), the
paper's alpha-aware blend. γ defaults to the paper's f / (D z_min): f the target focal length in pixels,
D the plane count, z_min the near bound, i.e. a neighbour's weight falls by e when its distance moves
the nearest plane by D pixels (LLFF's sampling limit); set ``gamma`` to override (in 1 / scene units).
Pixels no MPI covers stay black.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass, fields

import numpy as np
import torch
import torch.nn.functional as F

from sparself.capture.images import resize_image
from sparself.capture.scene import Camera, Scene
from sparself.core.geometry import Pose, inverse_depth_planes
from sparself.core.warp import homography_warp, plane_homographies, plane_sweep

log = logging.getLogger(__name__)
MIN_BLEND_WEIGHT = 1e-3  # the least a pixel of a weighted view counts in the blend of MPIs


@dataclass
class MpiConfig:
    """num_planes: D; neighbors: views besides the reference in each MPI's plane sweep; min_baseline: sweep
    neighbours are the nearest cameras at least this far from the reference, in units of LLFF's sampling
    limit D z_min / f (the baseline over which the nearest plane moves D pixels), so that denser captures
    add MPIs without shrinking each sweep's baseline (0: the plain nearest cameras, the default: on llff_bird at
    128 px every floor tried scored lower at every density, see benchmarks/oracle_check.py); sweep_synthetic:
    False draws sweep neighbours from the non-synthetic frames only, so added (synthesized) views add MPIs
    close to the target without entering any other view's depth estimate; weighted_sweeps: each view counts
    in a sweep's plane colours and cost by its per-pixel weight (``Scene.pixel_weight``: a synthesized view's
    weight x confidence), as a fit's loss counts it; render_k: MPIs
    blended per rendered view; box: cost box-filter side (odd); temperature: soft-argmin temperature on
    the normalised cost; gamma: blend falloff in 1 / scene units (None: f / (D z_min)); cache_size: MPIs
    kept in memory (each is D x 4 x H x W float32); max_side: build MPIs at most this large (None: the
    cameras' size)."""

    num_planes: int = 32
    neighbors: int = 4
    min_baseline: float = 0.0
    sweep_synthetic: bool = True
    weighted_sweeps: bool = True
    render_k: int = 5
    box: int = 3
    temperature: float = 0.1
    gamma: float | None = None
    cache_size: int = 8
    max_side: int | None = None

    def __post_init__(self) -> None:
        if self.num_planes < 2 or self.render_k < 1 or self.neighbors < 1 or self.box < 1 or self.box % 2 == 0:
            raise ValueError(f"invalid MpiConfig {self}")
        if self.min_baseline < 0:
            raise ValueError("MpiConfig.min_baseline must be >= 0")
        if self.temperature <= 0:
            raise ValueError("MpiConfig.temperature must be > 0")


@dataclass
class Mpi:
    """rgba: (D, 4, H, W) plane colours and alphas, nearest plane first; depths: (D,); K: (3, 3); pose;
    weight: (1, H, W) its reference view's per-pixel weight in the blend (``Scene.pixel_weight``), None: 1."""

    rgba: torch.Tensor
    depths: np.ndarray
    K: np.ndarray
    pose: Pose
    weight: torch.Tensor | None = None


def build_mpi(
    images: torch.Tensor,
    Ks: np.ndarray,
    w2cs: np.ndarray,
    pose: Pose,
    depths: np.ndarray,
    cfg: MpiConfig,
    weights: torch.Tensor | None = None,
) -> Mpi:
    """The MPI of view 0 of a neighbourhood.

    images: (S, 3, H, W), view 0 the reference; Ks: (S, 3, 3); w2cs: (S, 4, 4); depths: (D,) near first;
    weights: (S, 1, H, W) each view's per-pixel weight in the plane colours and the cost (None: all 1).
    """
    _, _, h, w = images.shape
    # the weights ride with a channel of ones: their ratio undoes the warp's fading at the image's edge
    src = images if weights is None else torch.cat([images, weights, torch.ones_like(weights)], 1)
    vol, valid = plane_sweep(src, Ks, w2cs, Ks[0], w2cs[0], depths, (h, w))
    cnt = valid.sum(0)  # (D, 1, H, W)
    if weights is None:
        mean = (valid * vol).sum(0) / cnt.clamp_min(1)  # (D, 3, H, W)
        var = (valid * (vol - mean) ** 2).sum(0).mean(1, keepdim=True) / (cnt - 1).clamp_min(1)
    else:
        edge = vol[:, :, 4:]
        wts = valid * torch.where(edge > 0, vol[:, :, 3:4] / edge.clamp_min(1e-12), torch.zeros_like(edge))
        mean, var = _weighted_moments(vol[:, :, :3], wts)
    cost = F.avg_pool2d(var, cfg.box, 1, cfg.box // 2, count_include_pad=False)
    informed = cnt >= 2
    worst = torch.where(informed, cost, torch.zeros_like(cost)).amax(0, keepdim=True)
    cost = torch.where(informed, cost, worst)
    cmin = cost.amin(0, keepdim=True)
    norm = (cost - cmin) / (cost.mean(0, keepdim=True) - cmin + 1e-4)
    p = torch.softmax(-norm / cfg.temperature, dim=0)  # (D, 1, H, W)
    before = torch.cumsum(p, 0) - p  # mass in front of each plane
    alpha = (p / (1.0 - before).clamp_min(1e-6)).clamp(0.0, 1.0)
    alpha[-1] = 1.0
    return Mpi(torch.cat([mean, alpha], 1).contiguous(), depths, Ks[0], pose)


def _weighted_moments(vol: torch.Tensor, wts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weighted mean colour and unbiased (reliability-weights) variance over views, as :func:`build_mpi`'s
    plain ones with every weight 1. vol: (S, D, 3, H, W); wts: (S, D, 1, H, W), 0 where a view is invalid.
    -> ((D, 3, H, W), (D, 1, H, W))."""
    v1 = wts.sum(0)
    mean = (wts * vol).sum(0) / v1.clamp_min(1e-12)
    dof = (v1 - (wts**2).sum(0) / v1.clamp_min(1e-12)).clamp_min(1e-6)
    return mean, (wts * (vol - mean) ** 2).sum(0).mean(1, keepdim=True) / dof


def render_mpi(mpi: Mpi, pose: Pose, K: np.ndarray, out_hw: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Warp every plane into the target camera and over-composite front to back.

    Returns (premultiplied colour (3, H, W), coverage (1, H, W)); with a per-pixel ``weight``, each plane
    sample counts its reference pixel's weight in both (so the blend of MPIs trusts confident pixels more).
    """
    # p_target ~ H p_ref for the plane z = depth of the reference camera; the warp needs target -> ref
    H = plane_homographies(
        torch.from_numpy(K)[None],
        torch.from_numpy(pose.w2c())[None],
        torch.from_numpy(mpi.K),
        torch.from_numpy(mpi.pose.w2c()),
        torch.from_numpy(mpi.depths),
    )[0]
    planes = mpi.rgba if mpi.weight is None else torch.cat([mpi.rgba, mpi.weight.expand(len(mpi.rgba), 1, -1, -1)], 1)
    warped, _ = homography_warp(planes, torch.linalg.inv(H).float(), out_hw)  # (D, 4 or 5, H, W), zero outside
    rgb, a = warped[:, :3], warped[:, 3:4]
    trans = torch.cumprod(torch.cat([torch.ones_like(a[:1]), 1.0 - a[:-1]], 0), 0)
    wgt = trans * a if mpi.weight is None else trans * a * warped[:, 4:5]
    return (wgt * rgb).sum(0), wgt.sum(0)


class MpiRenderer:
    """Renders poses from the MPIs of a scene's source views (built lazily, kept in an LRU cache)."""

    def __init__(self, scene: Scene, cfg: MpiConfig) -> None:
        if len(scene.frames) == 0:
            raise ValueError("MPI renderer needs at least one source view")
        self.scene = scene.resized(cfg.max_side) if cfg.max_side else scene
        self.cfg = cfg
        near, far = self.scene.depth_bounds()
        self.near = near
        self.depths = inverse_depth_planes(near, far, cfg.num_planes)
        self.centers = self.scene.centers()
        self._cache: OrderedDict[int, Mpi] = OrderedDict()

    def _neighbourhood(self, r: int) -> list[int]:
        """r and its sweep neighbours: the nearest cameras at least the minimum baseline away; when
        too few are, the farthest of the closer ones fill up (LLFF's rule, not the plain nearest)."""
        d = np.linalg.norm(self.centers - self.centers[r], axis=1)
        d[r] = np.inf
        if not self.cfg.sweep_synthetic:
            synthetic = np.array([f.synthetic for f in self.scene.frames])
            if (~synthetic).sum() > 1:  # keep the plain rule when too few real frames are left
                d[synthetic] = np.inf
        order = [int(i) for i in np.argsort(d, kind="stable") if np.isfinite(d[i])]
        floor = self.cfg.min_baseline * self.cfg.num_planes * self.near / self.scene.camera(r).fx
        wide = [i for i in order if d[i] >= floor]
        close = [i for i in order if d[i] < floor][::-1]
        return [r] + (wide + close)[: self.cfg.neighbors]

    def mpi(self, r: int) -> Mpi:
        """The MPI of source view r (built on first use)."""
        if r in self._cache:
            self._cache.move_to_end(r)
            return self._cache[r]
        sc = self.scene
        idx = self._neighbourhood(r)
        w, h = sc.image_size(r)
        imgs = [sc.load(i) for i in idx]
        imgs = [im if im.shape[:2] == (h, w) else resize_image(im, (w, h)) for im in imgs]
        # a neighbour with another image size is sampled with its own K; only the reference fixes the grid
        Ks = np.stack([sc.camera(i).K if sc.image_size(i) == (w, h) else sc.camera(i).resized(w, h).K for i in idx])
        w2cs = np.stack([sc.frames[i].pose.w2c() for i in idx])
        images = torch.from_numpy(np.stack(imgs).transpose(0, 3, 1, 2).copy()).float()
        # the reference counts fully in its own MPI (the blend weighs the MPI by it); its neighbours by their weights
        pws = [sc.pixel_weight(i) for i in idx]
        own = [None] + pws[1:]
        weights = None if not self.cfg.weighted_sweeps or all(p is None for p in own) else self._weights(own, (w, h))
        m = build_mpi(images, Ks, w2cs, sc.frames[r].pose, self.depths, self.cfg, weights)
        pw = pws[0]
        if pw is not None:  # a floor keeps a weight-0 view a gap filler where no other MPI reaches
            m.weight = torch.from_numpy(np.maximum(pw, MIN_BLEND_WEIGHT))[None]
        self._cache[r] = m
        while len(self._cache) > max(1, self.cfg.cache_size):
            self._cache.popitem(last=False)
        return m

    @staticmethod
    def _weights(pws: list[np.ndarray | None], size: tuple[int, int]) -> torch.Tensor:
        """(S, 1, H, W) the neighbourhood's pixel weights at ``size`` = (W, H), 1 where a view has none, with
        the blend's floor (a weight-0 view still shows where it is all there is)."""
        w, h = size
        maps = [
            np.ones((h, w), np.float32) if p is None else p if p.shape == (h, w) else resize_image(p, (w, h))
            for p in pws
        ]
        return torch.from_numpy(np.maximum(np.stack(maps), MIN_BLEND_WEIGHT))[:, None].float()

    def gamma(self, camera: Camera) -> float:
        """Blend falloff γ (1 / scene units): cfg.gamma or f / (D z_min)."""
        if self.cfg.gamma is not None:
            return float(self.cfg.gamma)
        return float(camera.fx / (self.cfg.num_planes * self.near))

    def render(self, pose: Pose, camera: Camera) -> np.ndarray:
        """Image of the scene seen by ``camera`` at ``pose``. -> (H, W, 3) float32 in [0, 1]."""
        hw = (camera.height, camera.width)
        dist = np.linalg.norm(self.centers - pose.center[None], axis=1)
        ks = np.argsort(dist, kind="stable")[: self.cfg.render_k]
        logw = -self.gamma(camera) * (dist[ks] - dist[ks].min())
        wts = np.exp(np.maximum(logw, -50.0))  # relative weights; the floor keeps far MPIs as gap fillers
        num = torch.zeros((3,) + hw, dtype=torch.float64)
        den = torch.zeros((1,) + hw, dtype=torch.float64)
        for k, wk in zip(ks, wts):
            col, cov = render_mpi(self.mpi(int(k)), pose, camera.K, hw)
            num += wk * col.double()
            den += wk * cov.double()
        img = num / den.clamp_min(1e-30)
        img = torch.where(den > 1e-30, img, torch.zeros_like(img))
        return img.permute(1, 2, 0).clamp(0.0, 1.0).float().numpy()


def fit(scene: Scene, cfg: MpiConfig | None = None, **overrides) -> MpiRenderer:
    """Reconstructor entry point: ``fit(scene, **cfg) -> renderer`` with ``renderer.render(pose, camera)``.

    cfg: an :class:`MpiConfig`; keyword overrides (its field names) are applied on top, unknown ones are
    ignored with a log message so one config dict can be shared by several reconstructors.
    """
    cfg = cfg or MpiConfig()
    names = {f.name for f in fields(MpiConfig)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        log.info("MPI renderer ignores options %s", unknown)
    if overrides:
        cfg = MpiConfig(**{**cfg.__dict__, **{k: v for k, v in overrides.items() if k in names}})
    return MpiRenderer(scene, cfg)
