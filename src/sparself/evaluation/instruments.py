"""The protocol's instruments: the network and baselines as synthesizers, the reconstructors, the scoring of a
render against a held-out photo (decoded only here), and the software versions recorded with the results."""

from __future__ import annotations

import platform
import subprocess
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from sparself.capture.images import load_image, resize_image
from sparself.capture.scene import Frame, Scene
from sparself.core import metrics
from sparself.core.errors import ConfigError, InputError
from sparself.core.interrupts import import_native
from sparself.core.outputs import current_work
from sparself.evaluation.config import EvalConfig
from sparself.model import default_weights
from sparself.recon import Renderer, backend, get_reconstructor
from sparself.recon.pool import FitPool, Fitter, side_by_side
from sparself.synthesis.baselines import BASELINES
from sparself.synthesis.synthesize import Synthesized, densify_scene, synthesize_with_confidence
from sparself.synthesis.train import train, train_resumable

# synthesize(scene, targets) -> (T, H, W, 3), or Synthesized (images + per-pixel confidence)
SynthFn = Callable[[Scene, list], "np.ndarray | Synthesized"]


def load_truth(frame: Frame, size: tuple[int, int]) -> np.ndarray:
    """Decode a real photo for scoring. The ONLY place the evaluation reads a held-out image."""
    if frame.image is not None:
        img = frame.image
        return img if (img.shape[1], img.shape[0]) == tuple(size) else resize_image(img, size)
    if frame.path is None:
        raise InputError(f"frame {frame.name}: no photo to score against")
    return load_image(frame.path, size=size)


@dataclass(frozen=True)
class ImageScores:
    """One image against its photo: PSNR (dB), SSIM, LPIPS (None: not scored)."""

    psnr: float
    ssim: float
    lpips: float | None


def score(pred: np.ndarray, truth: np.ndarray, use_lpips: bool) -> ImageScores:
    """(H, W, 3) prediction against (H, W, 3) truth in [0, 1]."""
    lp = metrics.lpips(pred, truth) if use_lpips else None
    return ImageScores(metrics.psnr(pred, truth), metrics.ssim(pred, truth), lp)


def versions() -> dict:
    """Versions of everything that produced the numbers (missing packages are None)."""
    out: dict[str, str | None] = {"python": platform.python_version(), "platform": platform.platform()}
    for name in ("sparself", "torch", "numpy", "pycolmap", "kornia", "cv2", "skimage"):
        try:
            mod = import_native(name)  # pycolmap's import would otherwise turn SIGTERM into a native abort
            out[name] = getattr(mod, "__version__", None)
        except Exception:
            out[name] = None
    try:
        out["git_commit"] = (
            subprocess.run(
                ["git", "rev-parse", "HEAD"],
                cwd=Path(__file__).resolve().parent,
                capture_output=True,
                text=True,
                timeout=10,
            ).stdout.strip()
            or None
        )
    except Exception:
        out["git_commit"] = None
    return out


def network_factory(cfg: EvalConfig) -> Callable[[Scene, int], SynthFn]:
    """The one adapter to the CNN-LSTM: ``make(inputs, seed)`` trains ``sparself.synthesis.train.train`` with
    ``cfg.train`` (seed, size and epochs from the evaluation) on the inputs, in a temporary run folder, and
    returns the bound ``synthesize(scene, targets) -> Synthesized`` (images and confidence). Inside a command's
    work folder (:func:`~sparself.core.outputs.current_work`) the run folder is kept there, and a stopped run
    continues from its checkpoint."""
    # resolved (and warned about) once, not once per scene and seed
    weights = cfg.train.weights if cfg.train.weights is not None else default_weights()
    base = replace(
        cfg.train, size=cfg.size, weights=weights, epochs=cfg.epochs if cfg.epochs is not None else cfg.train.epochs
    )

    def make(scene: Scene, seed: int) -> SynthFn:
        tcfg, work = replace(base, seed=seed), current_work()
        if work is None:
            with tempfile.TemporaryDirectory(prefix="sparself-eval-run-") as tmp:
                run = train(scene, Path(tmp) / "run", tcfg, progress=cfg.progress)
        else:  # kept for a stopped evaluation to resume from
            run = train_resumable(work / "runs", scene, tcfg, progress=cfg.progress)
        return lambda sc, targets, **_: synthesize_with_confidence(run, sc, targets)

    return make


def baseline_fns(names: Sequence[str]) -> dict[str, SynthFn]:
    unknown = [n for n in names if n not in BASELINES]
    if unknown:
        raise ConfigError(f"unknown baseline(s) {unknown}; known: {sorted(BASELINES)}")
    return {n: BASELINES[n] for n in names}


def reconstructor(name: str, cfg: EvalConfig) -> Fitter:
    """fit(scene) -> renderer for a reconstructor name (:func:`sparself.recon.get_reconstructor`), with
    the evaluation's settings applied; ``.many(scenes)`` fits several side by side where that pays. The CPU
    3DGS starts with the first of ``cfg.splat_far_reach`` (the others are for
    :func:`~sparself.evaluation.reach.choose_reach`)."""
    get_reconstructor(name)  # an unknown name fails here, before any fit
    base = dict(seed=cfg.recon_seed, progress=cfg.progress)
    splat: dict[str, float] = dict(base)
    if cfg.splat_steps_per_view is not None:
        splat.update(steps=0, min_steps_per_view=cfg.splat_steps_per_view)
    if cfg.splat_far_reach != (1.0,):
        splat.update(far_reach=cfg.splat_far_reach[0])
    kw = {
        "nerf": dict(steps=cfg.nerf_steps, seed=cfg.recon_seed, progress=cfg.progress),
        "gsplat": base,
        "3dgs": splat if backend("3dgs") == "splat" else base,  # the CPU path's setting: gsplat keeps its recipe
        "splat": splat,
    }.get(name, {})
    return Fitter(name, kw)


def fit_each(
    fit: Callable[[Scene], Renderer], scenes: list[Scene], seeds: list[int] | None = None, pool: FitPool | None = None
) -> Iterable[Renderer]:
    """A renderer per scene, in order: all at once, side by side where that pays, for a reconstructor with
    its settings (:class:`~sparself.recon.pool.Fitter`; scene k with reconstruction seed ``seeds[k]`` when
    given; by ``pool`` when given, else a pool of its own); one after the other as they are read for any other
    ``fit`` (a test's, which takes no seed)."""
    return fit.many(scenes, pool, seeds) if isinstance(fit, Fitter) else (fit(sc) for sc in scenes)


def fits_at_once(fit: Callable[[Scene], Renderer]) -> int:
    """How many fits of ``fit`` pay to run at once here: :func:`~sparself.recon.pool.side_by_side` for a
    reconstructor with its settings, 1 for any other ``fit`` (a test's, which runs in this process)."""
    return side_by_side(fit.name) if isinstance(fit, Fitter) else 1


def fit_seed(cfg: EvalConfig, seed: int) -> int:
    """The reconstruction seed paired with network seed ``seed``: every row of that seed (N alone included)
    is fitted with it, so that a row's gain over N is measured fit against fit, and the spread over seeds
    holds the reconstructor's own randomness, which on a sparse capture moves N alone by a dB or more."""
    return cfg.recon_seed + seed


def with_fit_seed(fit: Callable[[Scene], Renderer], seed: int) -> Callable[[Scene], Renderer]:
    """``fit`` with reconstruction seed ``seed`` where it takes one (itself otherwise)."""
    return fit.with_seed(seed) if isinstance(fit, Fitter) else fit


def paired(fit: Callable[[Scene], Renderer]) -> bool:
    """Whether ``fit``'s results depend on the reconstruction seed (so rows without the network's views are
    fitted once per seed, not once)."""
    return isinstance(fit, Fitter) and fit.seeded


def with_images(scene: Scene, extra: list[Frame], images, confidence: np.ndarray | None = None) -> Scene:
    """scene plus ``extra`` frames carrying in-memory images (and their confidence maps), sorted by capture
    index."""
    images = np.asarray(images, np.float32).reshape(len(extra), *np.shape(images)[1:])
    return densify_scene(scene, list(extra), images, confidence)


def images_and_confidence(out) -> tuple[np.ndarray, np.ndarray | None]:
    """A synthesizer's answer as (images, confidence or None): the network's is a Synthesized."""
    return (out.images, out.confidence) if isinstance(out, Synthesized) else (np.asarray(out), None)


def renders(renderer: Renderer, scene: Scene, frames: list[Frame]) -> np.ndarray:
    """(T, H, W, 3) renders of ``frames`` with the scene's cameras."""
    return np.stack([renderer.render(f.pose, scene.cameras[f.camera_id]) for f in frames])
