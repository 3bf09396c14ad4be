"""A compact NeRF that trains in minutes on a CPU at <= 128 px.

Design (chosen for 2 CPU cores, not for state-of-the-art quality):
- multi-resolution *dense* feature grids (an Instant-NGP hash grid without the hashing: at these
  resolutions the grids fit in memory, and trilinear lookups are one ``grid_sample`` per level),
  followed by a tiny MLP for density and view-dependent colour;
- the scene is normalised so the region the cameras look at is the unit ball, and space outside
  it is contracted into the ball of radius 2 (mip-NeRF 360's contraction), so forward-facing,
  object-centric and unbounded captures all fit one grid;
- coarse-only sampling, log-uniform in depth between the scene's near and far bounds, no
  occupancy grid; stratified jitter while training, bin centres when rendering (deterministic);
- a learned constant background colour for rays that leave the scene (black Middlebury
  backgrounds, white tables).

Rays follow COLMAP's pixel convention: pixel (row i, column j) has its centre at (j + 0.5, i + 0.5).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from sparself.capture.scene import Camera, Scene
from sparself.core.errors import ConfigError
from sparself.core.geometry import Pose
from sparself.recon.common import at_most_threads, prepare_fit

log = logging.getLogger(__name__)


@dataclass
class NerfConfig:
    """Settings of :func:`fit`. Defaults train in a few minutes at 64 px on 2 idle cores (about 0.2 s a step)."""

    steps: int = 1000
    batch_rays: int = 512
    n_samples: int = 32
    # grid resolution per level over the contracted cube; a 96^3 level triples the step time on a CPU
    levels: tuple[int, ...] = (16, 32, 64)
    features: int = 2  # features per level
    hidden: int = 64
    lr_grid: float = 2e-2
    lr_mlp: float = 3e-3
    lr_decay: float = 0.1  # final learning rate = lr * lr_decay (exponential schedule)
    tv_weight: float = 1e-4  # total-variation on the grids: fewer floaters from sparse views
    max_side: int | None = None  # resize the scene first (None: use it as given)
    seed: int = 0
    threads: int = 2
    chunk: int = 4096  # rays per chunk when rendering
    progress: bool = True
    bounds: tuple[float, float] | None = None  # override (near, far)
    device: str = "auto"  # "auto": CUDA when torch sees one, else the CPU (deterministic there only)
    extra: dict = field(default_factory=dict)


# ---- geometry helpers ---------------------------------------------------------------------------


def pixel_rays(pose: Pose, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Rays through every pixel centre of ``camera`` at ``pose``.

    Returns (origins (H*W, 3), directions (H*W, 3)) in world space; directions are scaled so their
    camera-space z component is 1, so the ray parameter t is the depth along the optical axis.
    """
    h, w = camera.height, camera.width
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d_cam = np.stack([(jj - camera.cx) / camera.fx, (ii - camera.cy) / camera.fy, np.ones_like(jj)], -1)
    d_world = d_cam.reshape(-1, 3) @ pose.R  # R^T d for each row
    o = np.broadcast_to(pose.center, d_world.shape)
    return np.ascontiguousarray(o), np.ascontiguousarray(d_world)


def scene_normalization(scene: Scene) -> tuple[np.ndarray, float]:
    """(centre (3,), radius) of the region the cameras look at; world x maps to (x - centre) / radius.

    From the sparse points when there are enough (median, 90th-percentile spread); otherwise the
    point closest to all optical axes in the least-squares sense, with radius half its median
    distance to the cameras; if the axes are (nearly) parallel, a point at mid depth in front of them.
    """
    if scene.points is not None and len(scene.points) >= 20:
        p = np.asarray(scene.points, dtype=np.float64)
        c: np.ndarray = np.median(p, axis=0)
        r = float(np.percentile(np.linalg.norm(p - c, axis=1), 90))
        if r > 1e-9:
            return c, r
    centres = scene.centers()
    axes = np.stack([f.pose.R[2] for f in scene.frames])  # optical axis in world = third row of R
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for o, d in zip(centres, axes):
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ o
    near, far = scene.depth_bounds()
    if np.linalg.cond(A) < 1e4:
        c = np.linalg.solve(A, b)
        dist = np.linalg.norm(centres - c, axis=1)
        in_front = np.mean(np.einsum("ij,ij->i", c - centres, axes) > 0)
        if in_front > 0.5:
            return c, max(float(np.median(dist)) * 0.5, 1e-6)
    mid = float(np.sqrt(near * max(far, near * 1.01)))
    c = centres.mean(0) + axes.mean(0) * mid
    return c, max(mid * 0.5, float(np.ptp(centres, axis=0).max()), 1e-6)


def contract(x: torch.Tensor) -> torch.Tensor:
    """mip-NeRF 360 contraction: identity inside the unit ball, |x| -> 2 - 1/|x| outside. (..., 3)."""
    n = x.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    return torch.where(n <= 1.0, x, (2.0 - 1.0 / n) * x / n)


# ---- the field ----------------------------------------------------------------------------------


class _Field(torch.nn.Module):
    """Multi-resolution dense grids + tiny MLP: contracted point (N, 3) in [-2, 2]^3 and unit view
    direction (N, 3) -> density (N,) >= 0 and colour (N, 3) in [0, 1]."""

    def __init__(self, levels: tuple[int, ...], features: int, hidden: int):
        super().__init__()
        self.grids = torch.nn.ParameterList(
            [torch.nn.Parameter(torch.empty(1, features, r, r, r).uniform_(-1e-2, 1e-2)) for r in levels]
        )
        nf = features * len(levels)
        self.sigma_net = torch.nn.Sequential(
            torch.nn.Linear(nf, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, 1 + 15)
        )
        self.color_net = torch.nn.Sequential(
            torch.nn.Linear(15 + 3, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, 3)
        )
        self.background = torch.nn.Parameter(torch.zeros(3))

    def features(self, xc: torch.Tensor) -> torch.Tensor:
        g = (xc / 2.0).view(1, -1, 1, 1, 3)  # grid_sample wants (x, y, z) in [-1, 1]
        feats = [
            F.grid_sample(grid, g, mode="bilinear", align_corners=True).view(grid.shape[1], -1) for grid in self.grids
        ]
        return torch.cat(feats, 0).T

    def forward(self, xc: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.sigma_net(self.features(xc))
        sigma = F.softplus(h[:, 0] - 1.0)
        rgb = torch.sigmoid(self.color_net(torch.cat([h[:, 1:], d], -1)))
        return sigma, rgb

    def tv(self) -> torch.Tensor:
        loss = self.grids[0].new_zeros(())  # exactly 0.0 + the terms, on the grids' device
        for g in self.grids:
            loss = (
                loss
                + (g[..., 1:, :, :] - g[..., :-1, :, :]).pow(2).mean()
                + (g[..., :, 1:, :] - g[..., :, :-1, :]).pow(2).mean()
                + (g[..., :, :, 1:] - g[..., :, :, :-1]).pow(2).mean()
            )
        return loss


def _render_rays(
    field_: _Field,
    o: torch.Tensor,
    d: torch.Tensor,
    near: float,
    far: float,
    n_samples: int,
    centre: torch.Tensor,
    radius: float,
    jitter: torch.Generator | None,
) -> torch.Tensor:
    """Volume-render rays o, d (R, 3) -> colours (R, 3). Samples log-uniform in depth in [near, far]."""
    R, kw = o.shape[0], dict[str, Any](dtype=o.dtype, device=o.device)
    u = (torch.arange(n_samples, **kw) + 0.5).expand(R, n_samples)
    if jitter is not None:
        u = u + (torch.rand(R, n_samples, generator=jitter, **kw) - 0.5)
    s = u / n_samples
    t = near * (far / near) ** s  # (R, S) depths
    edges = near * (far / near) ** (torch.arange(n_samples + 1, **kw) / n_samples)
    delta = (edges[1:] - edges[:-1]).expand(R, n_samples)
    pts = o[:, None, :] + t[..., None] * d[:, None, :]
    xc = contract((pts - centre) / radius)
    dn = F.normalize(d, dim=-1)[:, None, :].expand(R, n_samples, 3)
    sigma, rgb = field_(xc.reshape(-1, 3), dn.reshape(-1, 3))
    sigma, rgb = sigma.view(R, n_samples), rgb.view(R, n_samples, 3)
    # density in normalised units so the same initialisation works at any scene scale
    alpha = 1.0 - torch.exp(-sigma * delta * d.norm(dim=-1, keepdim=True) / radius)
    trans = torch.cumprod(torch.cat([torch.ones(R, 1, **kw), 1.0 - alpha + 1e-10], 1), 1)
    w = alpha * trans[:, :-1]
    color = (w[..., None] * rgb).sum(1) + trans[:, -1:] * torch.sigmoid(field_.background)
    return color


class NerfRenderer:
    """A fitted compact NeRF. ``render(pose, camera) -> (H, W, 3) float32 in [0, 1]``."""

    def __init__(
        self,
        field_: _Field,
        centre: np.ndarray,
        radius: float,
        near: float,
        far: float,
        config: NerfConfig,
        history: list[float],
    ):
        self.field = field_
        self.centre = centre
        self.radius = radius
        self.near, self.far = near, far
        self.config = config
        self.history = history  # training loss per step

    @torch.no_grad()
    def render(self, pose: Pose, camera: Camera) -> np.ndarray:
        o, d = pixel_rays(pose, camera)
        dev = self.field.background.device
        o_t = torch.from_numpy(o).float().to(dev)
        d_t = torch.from_numpy(d).float().to(dev)
        centre = torch.from_numpy(self.centre).float().to(dev)
        out = []
        for i in range(0, len(o_t), self.config.chunk):
            out.append(
                _render_rays(
                    self.field,
                    o_t[i : i + self.config.chunk],
                    d_t[i : i + self.config.chunk],
                    self.near,
                    self.far,
                    self.config.n_samples,
                    centre,
                    self.radius,
                    None,
                )
            )
        img = torch.cat(out).view(camera.height, camera.width, 3).clamp(0, 1)
        return img.cpu().numpy().astype(np.float32)


def fit(scene: Scene, config: NerfConfig | None = None, **overrides) -> NerfRenderer:
    """Train a compact NeRF on every frame of ``scene`` (images at the cameras' size).

    config: a :class:`NerfConfig`; keyword overrides replace its fields (``fit(scene, steps=300)``).
    Deterministic on CPU for a given ``config.seed``.
    """
    scene, cfg = prepare_fit(scene, NerfConfig, config, overrides, "NeRF")
    with at_most_threads(cfg.threads):
        return _fit(scene, cfg)


def fit_device(name: str) -> torch.device:
    """The torch device a reconstructor fits on: "auto" is CUDA when torch sees one, else the CPU."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError("device 'cuda' was asked for, but torch sees no CUDA device here")
    return torch.device(name)


def weighted_mse(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Weighted mean squared error of rays (R, 3) with per-ray weights (R,): sum w |e|^2 / (3 sum w); 0 when
    every weight is 0 (such rays must not move the fit)."""
    se = (pred - target).pow(2).sum(-1)
    return (weight * se).sum() / (3.0 * weight.sum()).clamp_min(1e-12)


def _training_rays(scene: Scene) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Origins, directions and colours of every pixel of every frame (R, 3), and their loss weights (R,)
    (:meth:`Scene.pixel_weight`), or None when every pixel counts 1."""
    origins, dirs, colors, weights = [], [], [], []
    for i, f in enumerate(scene.frames):
        o, d = pixel_rays(f.pose, scene.camera(i))
        origins.append(o)
        dirs.append(d)
        colors.append(scene.load(i).reshape(-1, 3))
        weights.append(scene.pixel_weight(i))
    w_all = None
    if any(w is not None for w in weights):
        w_all = torch.from_numpy(
            np.concatenate(
                [np.ones(len(o), np.float32) if w is None else w.reshape(-1) for o, w in zip(origins, weights)]
            )
        ).float()
    return (
        torch.from_numpy(np.concatenate(origins)).float(),
        torch.from_numpy(np.concatenate(dirs)).float(),
        torch.from_numpy(np.concatenate(colors)).float(),
        w_all,
    )


def _fit(scene: Scene, cfg: NerfConfig) -> NerfRenderer:
    torch.manual_seed(cfg.seed)
    dev = fit_device(cfg.device)
    gen = torch.Generator(device=dev).manual_seed(cfg.seed)
    near, far = cfg.bounds or scene.depth_bounds()
    near, far = float(max(near, 1e-4)), float(max(far, near * 1.05))
    centre, radius = scene_normalization(scene)
    o_all, d_all, c_all, w_all = _training_rays(scene)
    centre_t = torch.from_numpy(np.asarray(centre)).float().to(dev)
    o_all, d_all, c_all = o_all.to(dev), d_all.to(dev), c_all.to(dev)
    w_all = None if w_all is None else w_all.to(dev)

    # initialised on the CPU, so a seed gives the same start on every device
    field_ = _Field(tuple(cfg.levels), cfg.features, cfg.hidden).to(dev)
    with torch.no_grad():
        # start the background at the mean image colour (of the pixels that count): rays that leave the scene see it
        mean = c_all.mean(0) if w_all is None else (w_all[:, None] * c_all).sum(0) / w_all.sum().clamp_min(1e-12)
        field_.background.copy_(torch.logit(mean.clamp(0.02, 0.98)))
    opt = torch.optim.Adam(
        [
            {"params": list(field_.grids.parameters()), "lr": cfg.lr_grid},
            {
                "params": list(field_.sigma_net.parameters())
                + list(field_.color_net.parameters())
                + [field_.background],
                "lr": cfg.lr_mlp,
            },
        ],
        eps=1e-15,
    )
    gamma = cfg.lr_decay ** (1.0 / max(cfg.steps, 1))
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma)
    history: list[float] = []
    n = len(o_all)
    for _ in tqdm(range(cfg.steps), desc="nerf fit", disable=not cfg.progress, leave=False):
        idx = torch.randint(0, n, (min(cfg.batch_rays, n),), generator=gen, device=dev)
        pred = _render_rays(field_, o_all[idx], d_all[idx], near, far, cfg.n_samples, centre_t, radius, gen)
        loss = F.mse_loss(pred, c_all[idx]) if w_all is None else weighted_mse(pred, c_all[idx], w_all[idx])
        total = loss + cfg.tv_weight * field_.tv() if cfg.tv_weight > 0 else loss
        opt.zero_grad(set_to_none=True)
        total.backward()
        opt.step()
        sched.step()
        history.append(float(loss.detach()))
    log.info(
        "nerf: %d steps, final loss %.4f (near %.3g, far %.3g, radius %.3g)",
        cfg.steps,
        history[-1] if history else float("nan"),
        near,
        far,
        radius,
    )
    field_.eval()
    return NerfRenderer(field_, centre, radius, near, far, cfg, history)
