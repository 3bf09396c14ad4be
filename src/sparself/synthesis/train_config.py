"""The synthesizer's training options (:class:`TrainConfig`) and what follows from them and a scene: the
device, mixed precision, the backbone's input side, the sweep planes' depth range and the fc decoder's grid."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from sparself.capture.scene import Scene
from sparself.core.errors import ConfigError
from sparself.core.geometry import nearest_point_to_axes
from sparself.core.options import check_choices, option
from sparself.model.decoders import DecoderName

MIN_SIZE = 16  # px, long side of the training images

Amp = Literal["auto", "off", "fp16", "bf16"]  # mixed precision modes (amp_dtype)


@dataclass
class TrainConfig:
    """Training options (each field's help is its documentation; ``sparself train --help`` shows them).
    Defaults are CPU-sane: ``sparself densify`` on 25 images takes minutes on 2 cores. The fallback was
    measured (benchmarks/synthesis_quality.py): llff_bird 24.36 -> 24.56 dB, templeRing 23.38 -> 26.96 dB
    with "flow" instead of "blend"."""

    decoder: DecoderName = option(
        "sweep",
        "sweep: plane-sweep 3D CNN that generalises to new poses; fc: the paper's "
        "single linear layer (memorises its inputs)",
    )
    epochs: int = option(100, "training epochs")
    size: int = option(128, "long side in px of the training images (CPU-sane)")
    crop: int = option(64, "side in px of the random training crops (sweep decoder)")
    backbone_size: int = option(0, "ResNet-18 input side; 0 = auto: 224 (the paper's) on CUDA, 64 on CPU")
    batch_size: int = option(8, "leave-one-out targets per step; an epoch visits every training frame once")
    lr: float = option(1e-3, "Adam learning rate")
    planes: int = option(24, "depth planes of the sweep volume (uniform in disparity over the depth bounds)")
    channels: int = option(8, "feature channels of the sweep decoder's 3D CNN")
    windows: tuple[int, ...] = option(
        (5,), "box-filter sides (px, odd) of the matching cost the sweep decoder sees, one input channel each"
    )
    extra_layers: int = option(0, "additional 3x3x3 conv layers in the sweep decoder")
    gate: bool = option(
        True, "a learned per-pixel gate between the sweep's depth-resolved colour and the fallback (off: ablation)"
    )
    gate_init: float = option(
        0.0, "the gate's initial logit (0: half sweep, half fallback; negative: towards the fallback)"
    )
    ring_range: Literal["wide", "object"] = option(
        "object",
        "depth range of the sweep planes for a ring/object capture without "
        "bounds or sparse points: wide (0.5x-1.5x the camera distances to the common "
        "point) or object (the object that fits every view; measured: README)",
    )
    fallback: Literal["flow", "blend"] = option(
        "flow",
        "what the sweep decoder falls back to where depth is ambiguous: the two "
        "sources aligned by optical flow, or as they are",
    )
    ssim_weight: float = option(0.1, "loss = MSE + ssim_weight x (1 - SSIM) (7 px Gaussian window)")
    fc_side: int = option(48, "long side in px of the fc decoder's output grid (upsampled to the target)")
    end_targets: bool = option(
        False,
        "train on the leave-one-out targets at the ends of an open sequence too "
        "(extrapolated from the two sources on one side); off: only targets between "
        "their two sources, as the planned midpoints are (measured: README)",
    )
    context: bool = option(True, "give the decoder the LSTM output (off: zeros instead, an ablation)")
    sources: int = option(
        2,
        "source views per rendered view (sweep decoder): the two bracketing ones plus "
        "the nearest others by camera centre; above 2 the decoder weighs them per pixel "
        "with learned attention conditioned on the LSTM context (4 measured worse than 2: README)",
    )
    finetune_backbone: bool | None = option(
        None, "train ResNet-18 end to end (the paper); auto: yes on CUDA, no on CPU (features computed once)"
    )
    seed: int = option(0, "random seed (same seed, same result on CPU)")
    device: Literal["auto", "cpu", "cuda"] = option("auto", "where to train")
    holdout: tuple[int, ...] = option(
        (), "comma-separated frame positions (0-based) never used for training, e.g. 3,10"
    )
    checkpoint_every: int = option(5, "epochs between checkpoints")
    weights: str | None = option(
        None,
        "ResNet-18 ImageNet weights (torchvision's resnet18-f37072fd.pth); "
        "auto: the torch hub cache copy if present, else random initialisation with "
        "a warning; 'none': random initialisation, no warning",
    )
    amp: Amp = option("auto", "mixed precision (auto: fp16 with gradient scaling on CUDA, float32 on CPU)")
    compile: bool = option(False, "torch.compile the decoder in place (pays on GPU for long runs)")

    def __post_init__(self) -> None:
        self.holdout = tuple(int(i) for i in self.holdout)
        self.windows = tuple(int(k) for k in self.windows)
        if not self.windows or any(k < 1 or k % 2 == 0 for k in self.windows):
            raise ConfigError(f"windows must be odd sizes >= 1, got {self.windows}")
        check_choices(self)
        if int(self.sources) < 2:
            raise ConfigError(f"sources must be >= 2, got {self.sources}")
        for name in ("epochs", "size", "crop", "batch_size", "planes", "channels", "fc_side", "checkpoint_every"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.size < MIN_SIZE:  # optical flow and the sweep's matching windows need this much image
            raise ConfigError(
                f"training image size {self.size} px is too small: at least {MIN_SIZE} px "
                "(train: --size; densify: --out-size)"
            )

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["holdout"] = list(self.holdout)
        d["windows"] = list(self.windows)
        return d

    @classmethod
    def from_json(cls, d: dict) -> "TrainConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        # runs saved before these options existed used the plain blend, the wide ring range and every target
        d = {"fallback": "blend", "ring_range": "wide", "end_targets": True, **d}
        return cls(**{k: v for k, v in d.items() if k in known})


def amp_dtype(amp: Amp, device: torch.device) -> torch.dtype | None:
    """The autocast dtype of an ``amp`` mode on ``device`` (None: full float32)."""
    if amp == "auto":
        return torch.float16 if device.type == "cuda" else None
    return {"off": None, "fp16": torch.float16, "bf16": torch.bfloat16}[amp]


def autocast(device: torch.device, dtype: torch.dtype | None):
    """torch.autocast for ``dtype`` on ``device``, or a no-op context when dtype is None."""
    return torch.autocast(device.type, dtype=dtype or torch.float32, enabled=dtype is not None)


def resolve_device(name: str) -> torch.device:
    if name == "cuda" or (name == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise ConfigError("--device cuda asked for, but torch sees no CUDA device")
        return torch.device("cuda")
    return torch.device("cpu")


def backbone_side(cfg: TrainConfig, device: torch.device) -> int:
    """The backbone's input side: ``cfg.backbone_size``, or 224 (the paper's) on CUDA and 64 on CPU."""
    return cfg.backbone_size or (224 if device.type == "cuda" else 64)


def finetunes_backbone(cfg: TrainConfig, device: torch.device) -> bool:
    """Whether the backbone trains: ``cfg.finetune_backbone``, or yes on CUDA and no (frozen) on CPU."""
    return cfg.finetune_backbone if cfg.finetune_backbone is not None else device.type == "cuda"


def sweep_depth_bounds(scene: Scene, ring_range: str = "wide") -> tuple[float, float]:
    """(near, far) for the sweep planes: ``Scene.depth_bounds()`` when the scene knows its bounds or sparse
    points; otherwise, for cameras that look at a common point (a ring or an object capture, e.g.
    Middlebury), around the point nearest all optical axes: ``ring_range="wide"``: 0.5x to 1.5x the range
    of camera distances to it; ``"object"``: that range widened by the radius of the object such a capture
    can hold (one it sees whole from every camera fits within z_min x tan(half the field of view along
    the long side) of the point), within the wide range: the planes sample the object, not empty space."""
    if scene.bounds is not None or (scene.points is not None and len(scene.points) >= 10):
        return scene.depth_bounds()
    c = scene.centers()
    dirs = np.stack([f.pose.R[2] for f in scene.frames])  # optical axes in world coordinates
    x = nearest_point_to_axes(c, dirs)
    if x is not None:
        z = np.einsum("ij,ij->i", x - c, dirs)  # depth of the point in each camera
        if np.all(z > 0):
            r = z.min() * object_fov_tan(scene) if ring_range == "object" else np.inf
            return float(max(0.5 * z.min(), z.min() - r)), float(min(1.5 * z.max(), z.max() + r))
    return scene.depth_bounds()


def object_fov_tan(scene: Scene) -> float:
    """The smallest tan(half the field of view along the long image side) over the scene's cameras."""
    return float(min(max(c.width / (2 * c.K[0, 0]), c.height / (2 * c.K[1, 1])) for c in scene.cameras.values()))


def fc_grid(width: int, height: int, side: int) -> tuple[int, int]:
    """(h, w) of the fc decoder's output: long side ``side``, the images' aspect ratio."""
    s = side / max(width, height)
    return max(1, round(height * s)), max(1, round(width * s))
