"""Per-scene, leakage-free training of the CNN–LSTM view synthesizer.

Every training frame is predicted leave-one-out: from a sequence of the other training frames in which
its own step is a query step (pose + index, no image), see :mod:`sparself.model.cnn_lstm`. Frames listed
in ``holdout`` are removed from the scene before anything is loaded, so their images are never opened.

A run folder holds ``checkpoint.pt`` (model, optimizer, grad scaler, RNG states, epoch; written
atomically every ``checkpoint_every`` epochs and at the end), ``config.json`` (the :class:`TrainConfig`)
and ``train_log.csv`` (epoch, mean loss, wall seconds, CPU seconds of this process). ``resume=True``
continues from the checkpoint and ends with the same weights as an uninterrupted run (same seed, CPU).

CPU defaults (2 cores, 25 images): training images at 128 px on their long side, 64 px crops, backbone
input 64 px and frozen (features computed once), batch 8 targets, 100 epochs (4 steps each), 24 sweep
planes, 8 channels, plain-blend gate, Adam lr 1e-3, loss MSE + 0.1 (1 - SSIM). On CUDA the backbone
input is 224 px (the paper's) and it is
fine-tuned end to end, with fp16 autocast and gradient scaling. Measured on llff_bird (25 inputs, 1/4
resolution): about 240 CPU-seconds single-threaded for 100 epochs.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import logging
import os
import random
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from . import io as sio
from .errors import ConfigError, InputError
from .options import option
from .geometry import inverse_depth_planes, nearest_point_to_axes
from .model import CNNLSTM, PoseNorm, build_decoder, load_resnet18_weights
from .model.decoders import DECODERS, synthesis_loss
from .model.query import Queries, Sources, flow_aligned, leave_one_out, render
from .outputs import Input, atomic_file, check_not_input, check_output_dir, scene_inputs, write_marker
from .progress import show_progress
from .scene import Scene, one_size

log = logging.getLogger(__name__)

CHECKPOINT, CONFIG, LOG = "checkpoint.pt", "config.json", "train_log.csv"
MIN_SIZE = 16  # px, long side of the training images


@dataclass
class TrainConfig:
    """Training options (each field's help is its documentation; ``sparself train --help`` shows them).
    Defaults are CPU-sane: ``sparself densify`` on 25 images takes minutes on 2 cores. The fallback was
    measured (benchmarks/synthesis_quality.py): llff_bird 24.36 -> 24.56 dB, templeRing 23.38 -> 26.96 dB
    with "flow" instead of "blend"."""

    decoder: str = option("sweep", "sweep: plane-sweep 3D CNN that generalises to new poses; fc: the paper's "
                          "single linear layer (memorises its inputs)", choices=("sweep", "fc"))
    epochs: int = option(100, "training epochs")
    size: int = option(128, "long side in px of the training images (CPU-sane)")
    crop: int = option(64, "side in px of the random training crops (sweep decoder)")
    backbone_size: int = option(0, "ResNet-18 input side; 0 = auto: 224 (the paper's) on CUDA, 64 on CPU")
    batch_size: int = option(8, "leave-one-out targets per step; an epoch visits every training frame once")
    lr: float = option(1e-3, "Adam learning rate")
    planes: int = option(24, "depth planes of the sweep volume (uniform in disparity over the depth bounds)")
    channels: int = option(8, "feature channels of the sweep decoder's 3D CNN")
    windows: tuple[int, ...] = option((5,), "box-filter sides (px, odd) of the matching cost the sweep "
                                      "decoder sees, one input channel each")
    extra_layers: int = option(0, "additional 3x3x3 conv layers in the sweep decoder")
    gate: bool = option(True, "ablation: no learned per-pixel gate between the sweep's depth-resolved colour "
                        "and the fallback")
    gate_init: float = option(0.0, "the gate's initial logit (0: half sweep, half fallback; negative: "
                              "towards the fallback)")
    ring_range: str = option("object", "depth range of the sweep planes for a ring/object capture without "
                             "bounds or sparse points: wide (0.5x-1.5x the camera distances to the common "
                             "point) or object (the object that fits every view; measured: README)",
                             choices=("wide", "object"))
    fallback: str = option("flow", "what the sweep decoder falls back to where depth is ambiguous: the two "
                           "sources aligned by optical flow, or as they are", choices=("flow", "blend"))
    ssim_weight: float = option(0.1, "loss = MSE + ssim_weight x (1 - SSIM) (7 px Gaussian window)")
    fc_side: int = option(48, "long side in px of the fc decoder's output grid (upsampled to the target)")
    end_targets: bool = option(False, "train on the leave-one-out targets at the ends of an open sequence too "
                               "(extrapolated from the two sources on one side); off: only targets between "
                               "their two sources, as the planned midpoints are (measured: README)")
    context: bool = option(True, "ablation: zero the LSTM output given to the decoder")
    sources: int = option(2, "source views per rendered view (sweep decoder): the two bracketing ones plus "
                          "the nearest others by camera centre; above 2 the decoder weighs them per pixel "
                          "with learned attention conditioned on the LSTM context (4 measured worse than 2: README)")
    finetune_backbone: bool | None = option(None, "train ResNet-18 end to end (the paper); auto: yes on "
                                            "CUDA, no on CPU (features computed once)")
    seed: int = option(0, "random seed (same seed, same result on CPU)")
    device: str = option("auto", "where to train", choices=("auto", "cpu", "cuda"))
    holdout: tuple[int, ...] = option((), "comma-separated frame positions (0-based) never used for "
                                      "training, e.g. 3,10")
    checkpoint_every: int = option(5, "epochs between checkpoints")
    weights: str | None = option(None, "ResNet-18 ImageNet weights (torchvision's resnet18-f37072fd.pth); "
                                 "auto: the torch hub cache copy if present, else random initialisation with "
                                 "a warning; 'none': random initialisation, no warning")
    amp: str = option("auto", "mixed precision (auto: fp16 with gradient scaling on CUDA, float32 on CPU)",
                      choices=("auto", "off", "fp16", "bf16"))
    compile: bool = option(False, "torch.compile the decoder in place (pays on GPU for long runs)")

    def __post_init__(self) -> None:
        self.holdout = tuple(int(i) for i in self.holdout)
        self.windows = tuple(int(k) for k in self.windows)
        if not self.windows or any(k < 1 or k % 2 == 0 for k in self.windows):
            raise ConfigError(f"windows must be odd sizes >= 1, got {self.windows}")
        if self.decoder not in DECODERS:
            raise ConfigError(f"unknown decoder {self.decoder!r}; choose one of {', '.join(DECODERS)}")
        if int(self.sources) < 2:
            raise ConfigError(f"sources must be >= 2, got {self.sources}")
        for name in ("epochs", "size", "crop", "batch_size", "planes", "channels", "fc_side", "checkpoint_every"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.size < MIN_SIZE:  # optical flow and the sweep's matching windows need this much image
            raise ConfigError(f"training image size {self.size} px is too small: at least {MIN_SIZE} px "
                              "(train: --size; densify: --out-size)")
        if self.device not in ("auto", "cpu", "cuda"):
            raise ConfigError(f"device must be auto, cpu or cuda, got {self.device!r}")
        if self.ring_range not in ("wide", "object"):
            raise ConfigError(f"ring_range must be wide or object, got {self.ring_range!r}")
        if self.fallback not in ("blend", "flow"):
            raise ConfigError(f"fallback must be blend or flow, got {self.fallback!r}")
        if self.amp not in AMP_MODES:
            raise ConfigError(f"amp must be one of {', '.join(AMP_MODES)}, got {self.amp!r}")

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


# options that may differ between a run and its resumption
_RESUME_FREE = ("epochs", "device", "checkpoint_every", "weights", "amp", "compile")

AMP_MODES = ("auto", "off", "fp16", "bf16")


def amp_dtype(amp: str, device: torch.device) -> torch.dtype | None:
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


# ---- scene -> tensors ----------------------------------------------------------------------------

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


# ---- model construction and checkpoints ------------------------------------------------------------

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
        m.center, m.fc_hw, m.train_hw = tuple(m.center), tuple(m.fc_hw), tuple(m.train_hw)
        return m

    @property
    def norm(self) -> PoseNorm:
        return PoseNorm(tuple(self.center), float(self.scale))


def build_model(cfg: TrainConfig, meta: RunMeta) -> CNNLSTM:
    dec = build_decoder(cfg.decoder, channels=cfg.channels, fc_hw=tuple(meta.fc_hw), windows=cfg.windows,
                        extra_layers=cfg.extra_layers, gate=cfg.gate, gate_init=cfg.gate_init,
                        n_sources=cfg.sources)
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


def _config_mismatch(saved: TrainConfig, cfg: TrainConfig) -> list[str]:
    a, b = saved.to_json(), cfg.to_json()
    return [f"{k}={a[k]!r} (asked: {b[k]!r})" for k in a if k not in _RESUME_FREE and a[k] != b.get(k)]


def _read_checkpoint(path: Path) -> dict:
    if not path.is_file():
        raise InputError(f"{path}: no checkpoint (train a run first with `sparself train`)")
    try:
        ck = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:
        raise InputError(f"{path}: cannot read checkpoint ({type(e).__name__}: {e})") from None
    if not isinstance(ck, dict) or not {"model", "config", "meta"} <= set(ck):
        raise InputError(f"{path}: not a sparself checkpoint")
    return ck


def _load_state(model: torch.nn.Module, sd: dict, path: Path) -> None:
    try:
        model.load_state_dict(sd, strict=True)
    except RuntimeError as e:
        first = str(e).strip().splitlines()
        raise ConfigError(f"{path}: checkpoint does not fit this model ({first[-1].strip() if first else e})") from None


def load_run(path: Path | str, device: str = "cpu") -> Run:
    """Load a trained run folder (or its checkpoint file) for synthesis."""
    path = Path(path)
    ck_path = path / CHECKPOINT if path.is_dir() else path
    ck = _read_checkpoint(ck_path)
    cfg = TrainConfig.from_json(ck["config"])
    meta = RunMeta.from_json(ck["meta"])
    model = build_model(cfg, meta)
    _load_state(model, ck["model"], ck_path)
    model.to(resolve_device(device)).eval()
    return Run(model, cfg, meta, ck_path.parent)


def _rng_state(gen: torch.Generator) -> dict:
    return {"gen": gen.get_state(), "torch": torch.get_rng_state(), "numpy": np.random.get_state(),
            "python": random.getstate(),
            "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None}


def _set_rng_state(st: dict, gen: torch.Generator) -> None:
    gen.set_state(st["gen"])
    torch.set_rng_state(st["torch"])
    np.random.set_state(st["numpy"])
    random.setstate(st["python"])
    if st.get("cuda") is not None and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(st["cuda"])


@contextlib.contextmanager
def _deterministic(device: torch.device):
    """Deterministic kernels on CPU for the duration of training (restored afterwards)."""
    prev = torch.are_deterministic_algorithms_enabled()
    if device.type == "cpu":
        torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(prev)


# ---- the training step -----------------------------------------------------------------------------

@dataclass
class TrainData:
    """What the training step reads: the sources, every source as a leave-one-out query, and each
    query's ground truth at the decoder's output size (T, 3, h, w)."""

    sources: Sources
    queries: Queries
    truth: torch.Tensor
    trained: np.ndarray | None = None  # (T,) bool: the targets the loss visits (None: all)

    def __post_init__(self) -> None:
        if self.trained is None:
            self.trained = np.ones(len(self.queries), bool)

    def truth_of(self, targets: list[int], crops=None) -> torch.Tensor:
        if crops is None:
            return self.truth[np.asarray(targets)]
        return torch.stack([self.truth[t, :, y0:y0 + h, x0:x0 + w] for t, (y0, x0, h, w) in zip(targets, crops)])


def training_data(model: CNNLSTM, sources: Sources, cfg: TrainConfig, finetune: bool) -> TrainData:
    """Leave-one-out queries of every source (flow-aligned sources computed once per run), their ground
    truth, and the backbone inputs (for a frozen backbone, its outputs, computed once)."""
    hw = model.decoder.native_hw(sources.hw)
    queries = leave_one_out(sources, hw, cfg.sources)
    if cfg.fallback == "flow" and model.decoder.reads_sources:
        queries = flow_aligned(sources, queries)
    truth = sources.images
    if tuple(hw) != sources.hw:
        truth = F.interpolate(sources.images, size=tuple(hw), mode="bilinear", align_corners=False, antialias=True)
    bb = model.backbone_input(sources.images)
    feats = None
    if not finetune:
        model.backbone.requires_grad_(False)
        with torch.no_grad():
            feats = model.backbone(bb)
    return TrainData(dataclasses.replace(sources, backbone_input=bb, features=feats), queries, truth,
                     trained_targets(queries, cfg.end_targets))


def trained_targets(queries: Queries, end_targets: bool) -> np.ndarray:
    """Which leave-one-out targets the loss visits: all, or (``end_targets`` off) those between their
    pair (0 <= t <= 1), i.e. not the ends of an open sequence, which extrapolate twice as far as a planned
    extrapolation and whose flow fallback is clipped at t = -0.5; all when fewer than 2 would remain."""
    fr = queries.fractions
    inner = np.ones(len(queries), bool) if fr is None else (fr >= 0) & (fr <= 1)
    return np.ones(len(queries), bool) if end_targets or inner.sum() < 2 else inner


def _random_crops(data: TrainData, n: int, side: int, gen: torch.Generator) -> list[tuple[int, int, int, int]]:
    h, w = data.sources.hw
    c = min(side, h, w)
    ys = torch.randint(0, h - c + 1, (n,), generator=gen).tolist()
    xs = torch.randint(0, w - c + 1, (n,), generator=gen).tolist()
    return [(y, x, c, c) for y, x in zip(ys, xs)]


def _loo_loss(model: CNNLSTM, data: TrainData, targets: list[int], gen: torch.Generator,
              cfg: TrainConfig) -> torch.Tensor:
    """The loss of leave-one-out targets: random crops for a decoder that reads the sources (it is
    fully convolutional), whole images otherwise."""
    crops = _random_crops(data, len(targets), cfg.crop, gen) if model.decoder.reads_sources else None
    pred = render(model, data.sources, data.queries.select(targets), crops)
    return synthesis_loss(pred, data.truth_of(targets, crops), cfg.ssim_weight)


@torch.no_grad()
def predict_leave_one_out(run: Run, scene: Scene, targets: list[int]) -> np.ndarray:
    """Leave-one-out predictions, exactly as training computes them, of the training frames at positions
    ``targets`` (in the run's training order: ``scene`` minus holdout, sorted by index), whole images.
    -> (B, H, W, 3) at the decoder's output size for the training size."""
    dev = next(run.model.parameters()).device
    sources, meta = prepare(scene, run.cfg, dev)
    data = training_data(run.model, sources.posed(meta.norm, run.depths), run.cfg, run.meta.finetune_backbone)
    pred = render(run.model.eval(), data.sources, data.queries.select(list(targets)))
    return pred.clamp(0, 1).permute(0, 2, 3, 1).cpu().numpy()


def memory_estimate(small: Scene, cfg: TrainConfig, device: torch.device) -> dict[str, int]:
    """Rough bytes training will hold, from image sizes only (nothing is decoded). small: the training
    frames already resized to ``cfg.size``. Terms: the images as float32 tensors (exact); the backbone
    inputs, plus ~40 MB per view at 224 px of ResNet-18 activations when it is fine-tuned (a rule of thumb,
    scaled by area); weights, gradients and Adam moments (4 x 11.7 M float32 for ResNet-18 + the rest);
    one batch of sweep volumes (8 values x planes x crop^2) through the 3D CNN, kept for backward."""
    n = len(small)
    w, h = max(small.image_size(i) for i in range(n)) if n else (0, 0)
    bb = backbone_side(cfg, device)
    c = min(cfg.crop, h, w)
    est = {
        "images": n * 3 * h * w * 4,
        "backbone": n * 3 * bb * bb * 4 + (int(n * 40e6 * (bb / 224) ** 2) if finetunes_backbone(cfg, device) else 0),
        "parameters": 4 * 4 * 12_000_000,
        "sweep": cfg.batch_size * 8 * cfg.planes * c * c * 4 * (1 + 2 * cfg.channels) if DECODERS[cfg.decoder].reads_sources else 0,
    }
    est["total"] = sum(est.values())
    return est


def _available_memory(device: torch.device) -> int | None:
    try:
        if device.type == "cuda":
            return int(torch.cuda.mem_get_info(device)[0])
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, RuntimeError, AttributeError):
        return None


def log_memory_estimate(est: dict[str, int], device: torch.device, available: int | None = None) -> None:
    """Log the estimate (info); a warning when it exceeds half of the free memory of ``device``."""
    mb = {k: v / 2**20 for k, v in est.items()}
    text = (f"training memory estimate: ~{mb['total']:.0f} MB (images {mb['images']:.0f}, backbone "
            f"{mb['backbone']:.0f}, parameters {mb['parameters']:.0f}, sweep batch {mb['sweep']:.0f} MB)")
    free = available if available is not None else _available_memory(device)
    if free is not None and est["total"] > free / 2:
        log.warning("%s, more than half of the %.0f MB free on %s: lower --size or use fewer views",
                    text, free / 2**20, device.type)
    else:
        log.info("%s", text)


def _training_frames(scene: Scene, cfg: TrainConfig) -> Scene:
    """The scene minus ``cfg.holdout`` (never loaded), at one image size."""
    bad = [i for i in cfg.holdout if not 0 <= i < len(scene)]
    if bad:
        raise ConfigError(f"holdout positions {bad} are outside the scene's {len(scene)} frames")
    kept = scene.without(cfg.holdout)
    if len(kept) < 3:
        raise InputError(f"need at least 3 training frames, got {len(kept)} (scene {scene.source})")
    return one_size(kept)


def prepare(scene: Scene, cfg: TrainConfig, device: torch.device) -> tuple[Sources, RunMeta]:
    """The training frames (holdout removed, never loaded) as posed sources on ``device``, and the run's
    metadata."""
    src = _training_frames(scene, cfg)
    small = src.resized(cfg.size)
    log_memory_estimate(memory_estimate(small, cfg, device), device)  # before any image is loaded
    try:
        sources = Sources.from_scene(small)
    except ValueError as e:
        raise InputError(f"training frames of {scene.source} differ in size ({e}); resize them first") from None
    centers = np.stack([p.center for p in sources.poses])
    norm = PoseNorm(tuple(float(v) for v in centers.mean(0)), float(src.scale()))
    near, far = sweep_depth_bounds(src, cfg.ring_range)
    h, w = sources.hw
    meta = RunMeta(center=norm.center, scale=norm.scale, near=near, far=far, fc_hw=fc_grid(w, h, cfg.fc_side),
                   backbone_size=backbone_side(cfg, device), train_hw=(h, w),
                   sources=[src.frames[int(i)].name for i in sources.order],
                   scene=str(Path(scene.source).resolve()) if scene.source else None)  # absolute: any cwd
    return sources.to(device).posed(norm, inverse_depth_planes(near, far, cfg.planes)), meta


# ---- the training loop -----------------------------------------------------------------------------

@dataclass
class _Session:
    """Everything one training run holds: the model and its optimiser state, the data and the RNG."""

    model: CNNLSTM
    opt: torch.optim.Optimizer
    scaler: torch.amp.GradScaler
    gen: torch.Generator
    data: TrainData
    device: torch.device
    dtype: torch.dtype | None


def _resume_checkpoint(out: Path, cfg: TrainConfig, resume: bool, overwrite: bool) -> dict | None:
    """The checkpoint to continue from (None: a fresh run; the output folder is checked then)."""
    if resume and not (out / CHECKPOINT).exists() and (out / CONFIG).is_file():
        # killed before its first checkpoint: nothing to continue from, so the run starts again
        log.warning("%s: no checkpoint yet (the run stopped before its first one); starting from epoch 0", out)
        resume, overwrite = False, True
    if not resume:
        check_output_dir(out, overwrite)
        return None
    ck = _read_checkpoint(out / CHECKPOINT)
    diff = _config_mismatch(TrainConfig.from_json(ck["config"]), cfg)
    if diff:
        raise ConfigError(f"{out / CHECKPOINT} was trained with a different config: {', '.join(diff)}")
    return ck


def _session(scene: Scene, cfg: TrainConfig, device: torch.device, ck: dict | None,
             gen: torch.Generator) -> tuple[_Session, RunMeta]:
    """Model, data and optimiser for a run (weights from ``ck`` are loaded later, after compiling)."""
    sources, meta = prepare(scene, cfg, device)
    model = build_model(cfg, meta)
    meta.weights = load_resnet18_weights(model.backbone, cfg.weights) if ck is None else ck["meta"].get("weights", "random")
    model.to(device)
    meta.finetune_backbone = bool(finetunes_backbone(cfg, device))
    data = training_data(model, sources, cfg, meta.finetune_backbone)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    dtype = amp_dtype(cfg.amp, device)
    # gradient scaling only for fp16 on CUDA (bf16 has float32's range)
    scaler = torch.amp.GradScaler("cuda", enabled=dtype == torch.float16 and device.type == "cuda")
    if cfg.compile:
        model.decoder.compile()
        if meta.finetune_backbone:
            model.backbone.compile()
    return _Session(model, opt, scaler, gen, data, device, dtype), meta


def _epoch(s: _Session, cfg: TrainConfig) -> float:
    """One pass over every training frame in random order. -> mean loss."""
    n, total = len(s.data.sources), 0.0
    perm = [t for t in torch.randperm(n, generator=s.gen).tolist() if s.data.trained[t]]
    n = len(perm)
    for b in range(0, n, cfg.batch_size):
        targets = perm[b:b + cfg.batch_size]
        with autocast(s.device, s.dtype):
            loss = _loo_loss(s.model, s.data, targets, s.gen, cfg)  # float32 (synthesis_loss)
        s.opt.zero_grad(set_to_none=True)
        s.scaler.scale(loss).backward()
        s.scaler.step(s.opt)
        s.scaler.update()
        total += float(loss.detach()) * len(targets)
    return total / n


def _fit(s: _Session, out: Path, cfg: TrainConfig, meta: RunMeta, start: int, progress: bool | None) -> None:
    log.info("train: %d views at %dx%d px, epochs %d to %d; a checkpoint every %d epochs in %s", len(meta.sources),
             meta.train_hw[1], meta.train_hw[0], start + 1, cfg.epochs, cfg.checkpoint_every, out / CHECKPOINT)
    bar = tqdm(range(start, cfg.epochs), initial=start, total=cfg.epochs, desc="train", unit="epoch",
               disable=not show_progress() if progress is None else not progress)
    s.model.train()
    with _deterministic(s.device):
        for epoch in bar:
            t0, c0 = time.perf_counter(), time.process_time()
            mean = _epoch(s, cfg)
            bar.set_postfix(loss=f"{mean:.5f}")
            _append_log(out / LOG, epoch + 1, mean, time.perf_counter() - t0, time.process_time() - c0)
            if (epoch + 1) % cfg.checkpoint_every == 0 or epoch + 1 == cfg.epochs:
                _save_checkpoint(out / CHECKPOINT, s, epoch + 1, cfg, meta)
                if bar.disable:  # no bar (a log file, CI): say how far it is at each checkpoint
                    log.info("train: epoch %d/%d, loss %.5f, %.1f s/epoch", epoch + 1, cfg.epochs, mean,
                             time.perf_counter() - t0)
    s.model.eval()


def train(scene: Scene, out: Path | str, cfg: TrainConfig | None = None, *, resume: bool = False,
          overwrite: bool = False, progress: bool | None = None) -> Run:
    """Train a synthesizer on ``scene`` (minus ``cfg.holdout``) into the run folder ``out``.

    resume: continue from ``out/checkpoint.pt`` (its config must match ``cfg`` except epochs/device).
    Returns the trained :class:`Run` (model in eval mode, on the training device).
    """
    cfg = cfg or TrainConfig()
    out = Path(out)
    device = resolve_device(cfg.device)
    check_not_input(out, scene_inputs(scene))
    ck = _resume_checkpoint(out, cfg, resume, overwrite)
    if ck is not None:
        _check_resume_scene(out, RunMeta.from_json(ck["meta"]), scene, cfg)
    random.seed(cfg.seed)
    np.random.seed(cfg.seed)
    torch.manual_seed(cfg.seed)
    s, meta = _session(scene, cfg, device, ck, torch.Generator().manual_seed(cfg.seed))
    start = 0
    if ck is not None:
        _load_state(s.model, ck["model"], out / CHECKPOINT)
        s.opt.load_state_dict(ck["optimizer"])
        s.scaler.load_state_dict(ck["scaler"])
        _set_rng_state(ck["rng"], s.gen)
        start = int(ck["epoch"])
        log.info("resuming %s at epoch %d of %d", out, start, cfg.epochs)
    out.mkdir(parents=True, exist_ok=True)
    write_marker(out)
    if ck is None:  # a fresh run over an old one (--overwrite): the old checkpoint must never be resumed
        (out / CHECKPOINT).unlink(missing_ok=True)
    with atomic_file(out / CONFIG) as tmp:
        tmp.write_text(json.dumps(cfg.to_json(), indent=2))
    _truncate_log(out / LOG, start)
    _fit(s, out, cfg, meta, start, progress)
    return Run(s.model, cfg, meta, out)


def _check_resume_scene(out: Path, meta: RunMeta, scene: Scene, cfg: TrainConfig) -> None:
    from .consistency import run_scene_mismatch

    why = run_scene_mismatch(meta, scene, cfg.holdout)
    if why:
        raise ConfigError(f"{scene.source}: not the scene {out} was trained on ({meta.scene}): {why}; "
                          "resume with that scene, or train a new run")


def _save_checkpoint(path: Path, s: _Session, epoch: int, cfg: TrainConfig, meta: RunMeta) -> None:
    state = {"model": s.model.state_dict(), "optimizer": s.opt.state_dict(), "scaler": s.scaler.state_dict(),
             "rng": _rng_state(s.gen), "epoch": epoch, "config": cfg.to_json(), "meta": meta.to_json()}
    with atomic_file(path) as tmp:
        torch.save(state, tmp)


def _truncate_log(path: Path, epochs_done: int) -> None:
    """Keep the header and the rows of epochs <= epochs_done (a resumed run rewrites the rest)."""
    rows = []
    if epochs_done > 0 and path.is_file():
        with open(path, newline="") as f:
            rows = [r for r in csv.DictReader(f) if int(r["epoch"]) <= epochs_done]
    with atomic_file(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["epoch", "loss", "seconds", "cpu_seconds"])
        w.writeheader()
        w.writerows(rows)


def _append_log(path: Path, epoch: int, loss: float, seconds: float, cpu_seconds: float) -> None:
    with open(path, "a", newline="") as f:
        csv.writer(f).writerow([epoch, f"{loss:.6g}", f"{seconds:.3f}", f"{cpu_seconds:.3f}"])


def train_scene(scene_path: Path | str, out: Path | str, cfg: TrainConfig | None = None, *,
                resume: bool = False, overwrite: bool = False) -> Run:
    """`sparself train`: read a scene (anything ``sparself.io.read_scene`` accepts) and train on it."""
    check_not_input(out, [Input("scene", scene_path)])
    return train(sio.read_scene(Path(scene_path)), out, cfg, resume=resume, overwrite=overwrite)


def checkpoint_epoch(run_dir: Path | str) -> int | None:
    """The epoch of a run folder's checkpoint, or None when it has none (or an unreadable one)."""
    try:
        return int(_read_checkpoint(Path(run_dir) / CHECKPOINT)["epoch"])
    except (InputError, KeyError, TypeError, ValueError):
        return None
