"""3D Gaussian splatting through the optional ``gsplat`` package (``pip install sparself[gsplat]``), on CUDA.

``gsplat`` is imported only inside :func:`fit`; when the package or a CUDA device is missing a
:class:`SparselfError` says so, instead of a silent fallback. Cameras follow COLMAP's conventions
(world-to-camera matrices, pixel centres at +0.5), which is what ``gsplat.rasterization`` expects.

By default the fit is the CPU path's (:func:`sparself.recon.splat.fit_gaussians`) with gsplat drawing each
step (:func:`rasterizer`): the two render the same Gaussians to within float rounding, so the recipe tuned
on the CPU carries over and a GPU only makes it faster. gsplat's own recipe (:class:`GsplatConfig`) stays
selectable; on sparse captures it scored far below (19.8 against 26.7 dB from 25 llff_bird inputs).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from sparself.capture.scene import MIN_POINTS, Camera, Scene
from sparself.core.errors import SparselfError
from sparself.core.geometry import Pose
from sparself.recon.common import ViewOrder, frustum_points, photometric_loss
from sparself.recon.splat import EPS2D, NEAR_PLANE, Gaussians, Rasterizer, SplatConfig, fit_config, fit_gaussians

log = logging.getLogger(__name__)

_NEEDS = "gsplat reconstructor needs CUDA and `pip install sparself[gsplat]`"


@dataclass
class GsplatConfig:
    """The reference 3DGS recipe (what gsplat's own trainer runs, on a short schedule): :func:`fit` follows
    it when given one of these; by default it follows :class:`~sparself.recon.splat.SplatConfig`."""

    steps: int = 7000
    init_points: int = 20000  # random points in the scene bounds when the scene has no sparse points
    sh_degree: int = 3
    sh_increase_every: int = 1000
    ssim_lambda: float = 0.2
    lr_means: float = 1.6e-4
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_opacities: float = 5e-2
    lr_sh0: float = 2.5e-3
    lr_shN: float = 2.5e-3 / 20
    grow: bool = True  # gsplat's DefaultStrategy (clone/split/prune the Gaussians) when available
    view_order: ViewOrder = "epochs"  # each step's training view (sparself.recon.common.view_order)
    seed: int = 0
    max_side: int | None = None
    progress: bool = True


def _require_gsplat():
    """Import gsplat and torch with CUDA, or raise a clear SparselfError."""
    try:
        import torch
    except ImportError as e:  # pragma: no cover - torch is a hard dependency
        raise SparselfError(f"{_NEEDS}: torch is missing ({e})") from None
    try:
        import gsplat  # noqa: F401
    except Exception as e:  # ImportError, or a CUDA extension that fails to build/load
        raise SparselfError(f"{_NEEDS}: the gsplat package is not importable ({type(e).__name__}: {e})") from None
    if not torch.cuda.is_available():
        raise SparselfError(f"{_NEEDS}: no CUDA device is available (torch {torch.__version__})")
    return gsplat, torch


def available() -> tuple[bool, str]:
    """(True, "") when gsplat can run here, else (False, the reason)."""
    try:
        _require_gsplat()
    except SparselfError as e:
        return False, str(e)
    return True, ""


class GsplatRenderer:
    """Fitted Gaussians on CUDA. ``render(pose, camera) -> (H, W, 3) float32 in [0, 1]``."""

    backend = "cuda: gsplat.rasterization"

    def __init__(self, gaussians: Gaussians, sh_degree: int, background):
        self.gaussians = gaussians
        self.sh_degree = sh_degree
        self.background = background

    def render(self, pose: Pose, camera: Camera) -> np.ndarray:
        gsplat, torch = _require_gsplat()
        with torch.no_grad():
            img, _ = rasterizer(gsplat)(self.gaussians, pose, camera, self.background, self.sh_degree)
        return img.clamp(0, 1).cpu().numpy().astype(np.float32)


def rasterizer(gsplat) -> Rasterizer:
    """The :data:`~sparself.recon.splat.Rasterizer` of ``gsplat.rasterization``, on the Gaussians' device:
    the same image as the CPU path's (same 0.3 px^2 low-pass and near plane), and the screen-space gradients
    of the Gaussians it found in the view (radius > 0)."""
    import torch

    def raster(g: Gaussians, pose: Pose, camera: Camera, background, sh_degree: int):
        dev = g.means.device
        renders, _, info = gsplat.rasterization(
            means=g.means,
            quats=g.quats,
            scales=torch.exp(g.log_scales),
            opacities=torch.sigmoid(g.opacity_logits),
            colors=g.sh,
            viewmats=torch.tensor(pose.w2c(), dtype=torch.float32, device=dev)[None],
            Ks=torch.tensor(camera.K, dtype=torch.float32, device=dev)[None],
            width=camera.width,
            height=camera.height,
            sh_degree=sh_degree,
            backgrounds=background[None],
            packed=False,
            eps2d=EPS2D,
            near_plane=NEAR_PLANE,
        )
        means2d, radii = info["means2d"], info["radii"]  # (1, N, 2); (1, N) or (1, N, 2) by version
        if means2d.requires_grad:
            means2d.retain_grad()

        def screen():
            if means2d.grad is None:
                return None
            ids = (radii.reshape(len(g), -1) > 0).any(-1).nonzero()[:, 0]
            return ids, means2d.grad[0][ids]

        return renders[0], screen

    return raster


def _rasterize(gsplat, torch, params, poses, cameras, sh_degree, background, dev):
    viewmats = torch.tensor(np.stack([p.w2c() for p in poses]), dtype=torch.float32, device=dev)
    Ks = torch.tensor(np.stack([c.K for c in cameras]), dtype=torch.float32, device=dev)
    colors = torch.cat([params["sh0"], params["shN"]], 1)  # (N, K, 3)
    renders, alphas, info = gsplat.rasterization(
        means=params["means"],
        quats=params["quats"],
        scales=torch.exp(params["scales"]),
        opacities=torch.sigmoid(params["opacities"]),
        colors=colors,
        viewmats=viewmats,
        Ks=Ks,
        width=cameras[0].width,
        height=cameras[0].height,
        sh_degree=sh_degree,
        backgrounds=background.expand(len(poses), 3),
        packed=False,
        absgrad=False,
    )
    return renders, alphas, info


def initial_points(scene: Scene, cfg: GsplatConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) initial means and (P, 3) colours: the sparse points when known, else random in the
    depth-bounded frustum of the cameras (grey)."""
    if scene.points is not None and len(scene.points) >= MIN_POINTS:
        pts = np.asarray(scene.points, dtype=np.float32)
        if len(pts) > 200_000:
            pts = pts[rng.choice(len(pts), 200_000, replace=False)]
        return pts, np.full_like(pts, 0.5)
    pts = frustum_points(scene, cfg.init_points, rng).astype(np.float32)
    return pts, np.full_like(pts, 0.5)


def fit(scene: Scene, config: SplatConfig | GsplatConfig | None = None, **overrides) -> GsplatRenderer:
    """Fit 3D Gaussians to every frame of ``scene`` with gsplat on CUDA.

    config: a :class:`~sparself.recon.splat.SplatConfig` (the default): the CPU path's recipe, with gsplat
    drawing each step, so both paths fit the same way and a GPU only makes it faster; a
    :class:`GsplatConfig`: the reference recipe (7000 steps, SH degree 3, gsplat's clone/split strategy).
    Keyword overrides replace the config's fields. Raises SparselfError (before any work) when gsplat or
    CUDA is missing.
    """
    gsplat, torch = _require_gsplat()
    from sparself.recon.common import at_most_threads

    if isinstance(config, GsplatConfig):
        return _fit_reference(gsplat, torch, scene, config, overrides)
    scene, cfg = fit_config(scene, config, overrides, "gsplat")
    with at_most_threads(cfg.threads):
        g, _ = fit_gaussians(scene, cfg, rasterizer(gsplat), torch.device("cuda"))
    return GsplatRenderer(g, cfg.sh_degree, torch.tensor(cfg.background, dtype=torch.float32, device="cuda"))


def _fit_reference(gsplat, torch, scene: Scene, config: GsplatConfig, overrides: dict) -> GsplatRenderer:
    from sparself.recon.common import prepare_fit, view_order

    scene, cfg = prepare_fit(scene, GsplatConfig, config, overrides, "gsplat")
    from tqdm.auto import tqdm

    dev = torch.device("cuda")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    params = _init_params(torch, scene, cfg, rng, dev)
    scene_scale = float(scene.scale())
    lrs = {
        "means": cfg.lr_means * scene_scale,
        "scales": cfg.lr_scales,
        "quats": cfg.lr_quats,
        "opacities": cfg.lr_opacities,
        "sh0": cfg.lr_sh0,
        "shN": cfg.lr_shN,
    }
    optimizers = {k: torch.optim.Adam([{"params": params[k], "lr": lr, "name": k}], eps=1e-15) for k, lr in lrs.items()}
    strategy = state = None
    if cfg.grow:
        try:
            from gsplat.strategy import DefaultStrategy

            strategy = DefaultStrategy(refine_stop_iter=int(cfg.steps * 0.5), verbose=False)
            strategy.check_sanity(params, optimizers)
            state = strategy.initialize_state(scene_scale=scene_scale)
        except Exception as e:  # older gsplat without strategies: fit without growing the Gaussians
            log.warning("gsplat: clone/split strategy unavailable (%s); fitting without it", e)
            strategy = None
    images = [torch.tensor(scene.load(i), device=dev) for i in range(len(scene))]
    weights = [None if w is None else torch.tensor(w, device=dev) for w in map(scene.pixel_weight, range(len(scene)))]
    background = torch.zeros(3, device=dev)
    mean_decay = 0.01 ** (1.0 / max(cfg.steps, 1))
    order = view_order(len(scene), cfg.steps, rng, cfg.view_order)
    for step, i in enumerate(tqdm(order, total=cfg.steps, desc="gsplat fit", disable=not cfg.progress, leave=False)):
        sh_deg = min(step // cfg.sh_increase_every, cfg.sh_degree)
        render, _, info = _rasterize(
            gsplat, torch, params, [scene.frames[i].pose], [scene.camera(i)], sh_deg, background, dev
        )
        if strategy is not None:
            strategy.step_pre_backward(params, optimizers, state, step, info)
        loss = photometric_loss(render, images[i][None], cfg.ssim_lambda, weights[i])
        loss.backward()
        if strategy is not None:
            strategy.step_post_backward(params, optimizers, state, step, info, packed=False)
        for opt in optimizers.values():
            opt.step()
            opt.zero_grad(set_to_none=True)
        for g in optimizers["means"].param_groups:
            g["lr"] *= mean_decay
    log.info("gsplat: %d Gaussians after %d steps", len(params["means"]), cfg.steps)
    sh = torch.cat([params["sh0"], params["shN"]], 1)
    fields = (params["means"], params["quats"], params["scales"], params["opacities"], sh)
    return GsplatRenderer(Gaussians(*(t.detach() for t in fields)), cfg.sh_degree, background)


def _init_params(torch, scene: Scene, cfg: GsplatConfig, rng, dev):
    """Gaussians at the SfM points (or sampled ones): means, log scales, rotations, opacities, SH colours."""
    pts, cols = initial_points(scene, cfg, rng)
    means = torch.tensor(pts, device=dev)
    # initial scale: distance to the 3 nearest neighbours (log), as in the reference implementation
    with torch.no_grad():  # on up to 4096 sampled points, in chunks: a full cdist would not fit in memory
        probe = means[torch.randperm(len(means), device=dev)[:4096]]
        knn = torch.cat(
            [
                torch.cdist(c, means).topk(min(4, len(means)), largest=False).values[:, 1:].mean(1)
                for c in probe.split(256)
            ]
        ).clamp_min(1e-7)
        s0 = float(torch.log(knn.mean()))
    n = len(means)
    sh0 = (torch.tensor(cols, device=dev) - 0.5) / 0.28209479177387814
    K = (cfg.sh_degree + 1) ** 2
    params = torch.nn.ParameterDict(
        {
            "means": torch.nn.Parameter(means),
            "scales": torch.nn.Parameter(torch.full((n, 3), s0, device=dev)),
            "quats": torch.nn.Parameter(torch.nn.functional.normalize(torch.randn(n, 4, device=dev), dim=-1)),
            "opacities": torch.nn.Parameter(torch.logit(torch.full((n,), 0.1, device=dev))),
            "sh0": torch.nn.Parameter(sh0[:, None, :]),
            "shN": torch.nn.Parameter(torch.zeros(n, K - 1, 3, device=dev)),
        }
    )
    return params


__all__ = ["GsplatConfig", "GsplatRenderer", "available", "fit", "rasterizer"]
