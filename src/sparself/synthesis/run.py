"""A trained run: its model, config and pose normalisation, read back from ``checkpoint.pt``, and whether
a scene belongs to it.

A run records its training views' names and the centre and scale of their cameras (``RunMeta``: sources,
center, scale); a scene that differs in any of them is another capture, or another subset of it, and the
network's pose normalisation and its learned views do not apply to it.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from sparself.capture.io import detect_format
from sparself.capture.io.dense_photos import dense_scene_of_run
from sparself.capture.scene import Scene
from sparself.core.errors import ConfigError, InputError
from sparself.core.geometry import inverse_depth_planes
from sparself.model import CNNLSTM, PoseNorm, build_decoder
from sparself.synthesis.train_config import TrainConfig, resolve_device

log = logging.getLogger(__name__)

CHECKPOINT = "checkpoint.pt"


CONFIG = "config.json"


@dataclass
class RunMeta:
    """What a run needs besides its config to place new poses: the pose normalisation (center, scale),
    the sweep planes' depth range (near, far), the fc decoder's grid, the backbone's input side, the
    training image size, the training frames' names, the scene's path, the backbone's initial weights
    and whether the backbone was fine-tuned. Saved in the checkpoint as a dict (:meth:`to_json`)."""

    center: tuple[float, float, float]
    scale: float
    near: float
    far: float
    fc_hw: tuple[int, int]
    backbone_size: int
    train_hw: tuple[int, int]
    sources: list[str]
    scene: str | None
    weights: str = "random"
    finetune_backbone: bool = True

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(center=list(self.center), fc_hw=list(self.fc_hw), train_hw=list(self.train_hw))
        return d

    @classmethod
    def from_json(cls, d: dict) -> "RunMeta":
        known = {f.name for f in dataclasses.fields(cls)}
        m = cls(**{k: v for k, v in d.items() if k in known})
        c, fc, hw = m.center, m.fc_hw, m.train_hw  # lists in JSON
        m.center, m.fc_hw, m.train_hw = (c[0], c[1], c[2]), (fc[0], fc[1]), (hw[0], hw[1])
        return m

    @property
    def norm(self) -> PoseNorm:
        return PoseNorm(self.center, float(self.scale))


def build_model(cfg: TrainConfig, meta: RunMeta) -> CNNLSTM:
    dec = build_decoder(
        cfg.decoder,
        channels=cfg.channels,
        fc_hw=meta.fc_hw,
        windows=cfg.windows,
        extra_layers=cfg.extra_layers,
        gate=cfg.gate,
        gate_init=cfg.gate_init,
        n_sources=cfg.sources,
    )
    return CNNLSTM(dec, backbone_size=meta.backbone_size, context=cfg.context)


@dataclass
class Run:
    """A trained synthesizer: the model, its config and what it needs to place new poses."""

    model: CNNLSTM
    cfg: TrainConfig
    meta: RunMeta
    path: Path | None = None

    @property
    def norm(self) -> PoseNorm:
        return self.meta.norm

    @property
    def depths(self) -> np.ndarray:
        return inverse_depth_planes(self.meta.near, self.meta.far, self.cfg.planes)

    def uses_flow(self) -> bool:
        """Whether the decoder reads the sources aligned to each query by optical flow."""
        return self.cfg.fallback == "flow" and self.model.decoder.reads_sources


def read_checkpoint(path: Path) -> dict:
    if not path.is_file():
        raise InputError(f"{path}: no checkpoint (train a run first with `sparself train`)")
    try:
        ck = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:
        raise InputError(f"{path}: cannot read checkpoint ({type(e).__name__}: {e})") from None
    if not isinstance(ck, dict) or not {"model", "config", "meta"} <= set(ck):
        raise InputError(f"{path}: not a sparself checkpoint")
    return ck


def load_state(model: torch.nn.Module, sd: dict, path: Path) -> None:
    try:
        model.load_state_dict(sd, strict=True)
    except RuntimeError as e:
        first = str(e).strip().splitlines()
        raise ConfigError(f"{path}: checkpoint does not fit this model ({first[-1].strip() if first else e})") from None


def load_run(path: Path | str, device: str = "cpu") -> Run:
    """Load a trained run folder (or its checkpoint file) for synthesis."""
    path = Path(path)
    ck_path = path / CHECKPOINT if path.is_dir() else path
    ck = read_checkpoint(ck_path)
    cfg = TrainConfig.from_json(ck["config"])
    meta = RunMeta.from_json(ck["meta"])
    model = build_model(cfg, meta)
    load_state(model, ck["model"], ck_path)
    model.to(resolve_device(device)).eval()
    return Run(model, cfg, meta, ck_path.parent)


def run_scene_mismatch(meta: "RunMeta", scene: Scene, holdout: tuple[int, ...] = ()) -> str | None:
    """How ``scene`` (minus ``holdout``) differs from the run's training views, or None if it does not.
    Reads no image."""
    sub = scene.without(holdout)
    names = sorted(f.name for f in sub.frames)
    if len(meta.sources) != len(names):
        return f"the run was trained on {len(meta.sources)} views, this scene has {len(names)}"
    odd = sorted(set(map(str, meta.sources)) ^ set(names))
    if odd:
        return f"other views (in only one of the two: {', '.join(odd[:3])}{', ...' if len(odd) > 3 else ''})"
    if len(sub):
        tol = 1e-3 * max(float(meta.scale), 1e-12)
        if (
            np.linalg.norm(sub.centers().mean(0) - np.asarray(meta.center, float)) > tol
            or abs(sub.scale() - float(meta.scale)) > tol
        ):
            return "same view names, but the cameras are elsewhere (another capture?)"
    return None


def recorded_scene(meta: "RunMeta", run_path: Path) -> Path:
    """The scene a run was trained on, as recorded, while it holds poses; else the dense scene ``densify`` wrote
    beside the run (a run trained on photos posed by SfM: only the dense scene holds their poses); InputError
    saying "pass --scene" when neither is there."""
    p = Path(meta.scene) if meta.scene else None
    if p is not None and p.exists() and _is_scene(p):
        return p
    beside = dense_scene_of_run(run_path)
    if beside is not None:
        log.info("%s: synthesizing from the dense scene beside the run, %s", run_path, beside)
        return beside
    if p is None:
        raise InputError(f"{run_path}: the run does not record its scene; pass --scene")
    if not p.exists():
        raise InputError(
            f"{run_path}: the run's scene {p} is not there any more (moved or deleted?); "
            "pass --scene with its new location"
        )
    return p  # reading it says what is wrong with it


def _is_scene(path: Path) -> bool:
    try:
        detect_format(path)
    except InputError:
        return False
    return True
