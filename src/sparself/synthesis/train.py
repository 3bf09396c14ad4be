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
planes, 8 channels, a learned gate between the sweep and an optical-flow fallback, Adam lr 1e-3,
loss MSE + 0.1 (1 - SSIM). On CUDA the backbone
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
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from sparself.capture import io as sio
from sparself.capture.scene import Scene, one_size
from sparself.core.content import digest
from sparself.core.errors import ConfigError, InputError
from sparself.core.geometry import inverse_depth_planes
from sparself.core.outputs import Input, atomic_file, check_not_input, check_output_dir, scene_inputs, write_marker
from sparself.core.progress import show_progress
from sparself.model import CNNLSTM, PoseNorm, load_resnet18_weights
from sparself.model.decoders import DECODERS, synthesis_loss
from sparself.model.query import Queries, Sources, flow_aligned, leave_one_out, render
from sparself.synthesis.run import CHECKPOINT, CONFIG, Run, RunMeta, build_model, load_state, read_checkpoint
from sparself.synthesis.train_config import (
    TrainConfig,
    amp_dtype,
    autocast,
    backbone_side,
    fc_grid,
    finetunes_backbone,
    resolve_device,
    sweep_depth_bounds,
)

log = logging.getLogger(__name__)

LOG = "train_log.csv"


# options that may differ between a run and its resumption
_RESUME_FREE = ("epochs", "device", "checkpoint_every", "weights", "amp", "compile")


# ---- scene -> tensors ----------------------------------------------------------------------------


# ---- model construction and checkpoints ------------------------------------------------------------


def _config_mismatch(saved: TrainConfig, cfg: TrainConfig) -> list[str]:
    a, b = saved.to_json(), cfg.to_json()
    return [f"{k}={a[k]!r} (asked: {b[k]!r})" for k in a if k not in _RESUME_FREE and a[k] != b.get(k)]


def _rng_state(gen: torch.Generator) -> dict:
    return {
        "gen": gen.get_state(),
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),
        "python": random.getstate(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None,
    }


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
    trained: np.ndarray  # (T,) bool: the targets the loss visits

    def truth_of(self, targets: list[int], crops=None) -> torch.Tensor:
        if crops is None:
            return self.truth[np.asarray(targets)]
        return torch.stack([self.truth[t, :, y0 : y0 + h, x0 : x0 + w] for t, (y0, x0, h, w) in zip(targets, crops)])


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
    return TrainData(
        dataclasses.replace(sources, backbone_input=bb, features=feats),
        queries,
        truth,
        trained_targets(queries, cfg.end_targets),
    )


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


def _loo_loss(
    model: CNNLSTM, data: TrainData, targets: list[int], gen: torch.Generator, cfg: TrainConfig
) -> torch.Tensor:
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
        "sweep": cfg.batch_size * 8 * cfg.planes * c * c * 4 * (1 + 2 * cfg.channels)
        if DECODERS[cfg.decoder].reads_sources
        else 0,
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
    text = (
        f"training memory estimate: ~{mb['total']:.0f} MB (images {mb['images']:.0f}, backbone "
        f"{mb['backbone']:.0f}, parameters {mb['parameters']:.0f}, sweep batch {mb['sweep']:.0f} MB)"
    )
    free = available if available is not None else _available_memory(device)
    if free is not None and est["total"] > free / 2:
        log.warning(
            "%s, more than half of the %.0f MB free on %s: lower --size or use fewer views",
            text,
            free / 2**20,
            device.type,
        )
    else:
        log.info("%s", text)


MIN_TRAIN = 3  # training frames a run needs (each is predicted from the others)


def check_holdout(holdout: Sequence[int], scene: Scene) -> None:
    """Refuse --holdout positions that are not frames of ``scene`` (ConfigError naming them)."""
    bad = [i for i in holdout if not 0 <= i < len(scene)]
    if bad:
        raise ConfigError(
            f"--holdout {','.join(map(str, bad))}: outside the scene's {len(scene)} views "
            f"(positions 0 to {len(scene) - 1})"
        )


def _training_frames(scene: Scene, cfg: TrainConfig) -> Scene:
    """The scene minus ``cfg.holdout`` (never loaded), at one image size."""
    check_holdout(cfg.holdout, scene)
    kept = scene.without(cfg.holdout)
    if len(kept) < MIN_TRAIN:
        raise InputError(f"need at least {MIN_TRAIN} training frames, got {len(kept)} (scene {scene.source})")
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
    mean = centers.mean(0)
    norm = PoseNorm((float(mean[0]), float(mean[1]), float(mean[2])), float(src.scale()))
    near, far = sweep_depth_bounds(src, cfg.ring_range)
    h, w = sources.hw
    meta = RunMeta(
        center=norm.center,
        scale=norm.scale,
        near=near,
        far=far,
        fc_hw=fc_grid(w, h, cfg.fc_side),
        backbone_size=backbone_side(cfg, device),
        train_hw=(h, w),
        sources=[src.frames[int(i)].name for i in sources.order],
        scene=str(Path(scene.source).resolve()) if scene.source else None,
    )  # absolute: any cwd
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
    ck = read_checkpoint(out / CHECKPOINT)
    diff = _config_mismatch(TrainConfig.from_json(ck["config"]), cfg)
    if diff:
        raise ConfigError(f"{out / CHECKPOINT} was trained with a different config: {', '.join(diff)}")
    return ck


def _session(
    scene: Scene, cfg: TrainConfig, device: torch.device, ck: dict | None, gen: torch.Generator
) -> tuple[_Session, RunMeta]:
    """Model, data and optimiser for a run (weights from ``ck`` are loaded later, after compiling)."""
    sources, meta = prepare(scene, cfg, device)
    model = build_model(cfg, meta)
    meta.weights = (
        load_resnet18_weights(model.backbone, cfg.weights) if ck is None else ck["meta"].get("weights", "random")
    )
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
        targets = perm[b : b + cfg.batch_size]
        with autocast(s.device, s.dtype):
            loss = _loo_loss(s.model, s.data, targets, s.gen, cfg)  # float32 (synthesis_loss)
        s.opt.zero_grad(set_to_none=True)
        s.scaler.scale(loss).backward()
        s.scaler.step(s.opt)
        s.scaler.update()
        total += float(loss.detach()) * len(targets)
    return total / n


def _fit(s: _Session, out: Path, cfg: TrainConfig, meta: RunMeta, start: int, progress: bool | None) -> None:
    log.info(
        "train: %d views at %dx%d px, epochs %d to %d; a checkpoint every %d epochs in %s",
        len(meta.sources),
        meta.train_hw[1],
        meta.train_hw[0],
        start + 1,
        cfg.epochs,
        cfg.checkpoint_every,
        out / CHECKPOINT,
    )
    bar = tqdm(
        range(start, cfg.epochs),
        initial=start,
        total=cfg.epochs,
        desc="train",
        unit="epoch",
        disable=not show_progress() if progress is None else not progress,
    )
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
                    log.info(
                        "train: epoch %d/%d, loss %.5f, %.1f s/epoch",
                        epoch + 1,
                        cfg.epochs,
                        mean,
                        time.perf_counter() - t0,
                    )
    s.model.eval()


def train(
    scene: Scene,
    out: Path | str,
    cfg: TrainConfig | None = None,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool | None = None,
) -> Run:
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
        load_state(s.model, ck["model"], out / CHECKPOINT)
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


def train_resumable(parent: Path, scene: Scene, cfg: TrainConfig, progress: bool | None = None) -> Run:
    """:func:`train` in a run folder under ``parent`` named by a digest of ``scene`` and ``cfg`` (less the options a
    resumed run may change, such as the epochs): a run stopped there is continued from its checkpoint, and one
    with other options or another scene trains in a folder of its own."""
    same = {k: v for k, v in cfg.to_json().items() if k not in _RESUME_FREE}
    out = Path(parent) / digest((scene, same))[:20]
    return train(scene, out, cfg, resume=(out / CONFIG).is_file(), overwrite=True, progress=progress)


def _check_resume_scene(out: Path, meta: RunMeta, scene: Scene, cfg: TrainConfig) -> None:
    from sparself.synthesis.run import run_scene_mismatch

    why = run_scene_mismatch(meta, scene, cfg.holdout)
    if why:
        raise ConfigError(
            f"{scene.source}: not the scene {out} was trained on ({meta.scene}): {why}; "
            "resume with that scene, or train a new run"
        )


def _save_checkpoint(path: Path, s: _Session, epoch: int, cfg: TrainConfig, meta: RunMeta) -> None:
    state = {
        "model": s.model.state_dict(),
        "optimizer": s.opt.state_dict(),
        "scaler": s.scaler.state_dict(),
        "rng": _rng_state(s.gen),
        "epoch": epoch,
        "config": cfg.to_json(),
        "meta": meta.to_json(),
    }
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


def train_scene(
    scene_path: Path | str,
    out: Path | str,
    cfg: TrainConfig | None = None,
    *,
    resume: bool = False,
    overwrite: bool = False,
) -> Run:
    """`sparself train`: read a scene (anything ``sparself.capture.io.read_scene`` accepts) and train on it."""
    check_not_input(out, [Input("scene", scene_path)])
    return train(sio.read_scene(Path(scene_path)), out, cfg, resume=resume, overwrite=overwrite)


def checkpoint_epoch(run_dir: Path | str) -> int | None:
    """The epoch of a run folder's checkpoint, or None when it has none (or an unreadable one)."""
    try:
        return int(read_checkpoint(Path(run_dir) / CHECKPOINT)["epoch"])
    except (InputError, KeyError, TypeError, ValueError):
        return None
