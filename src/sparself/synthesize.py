"""Synthesis with a trained CNN–LSTM run, scene densification, and the whole photos -> dense scene pipeline.

Novel poses are query steps (pose + fractional index, no image) inserted among all source frames; each
target gets its own sequence (the sources plus its query step), and all targets run as one batch.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .errors import InputError
from .model import sweep_volume
from .outputs import atomic_dir
from .scene import Frame, Scene, one_size
from .train import (Run, TrainConfig, amp_dtype, autocast, bracket, bracket_fraction, flow_aligned, index_positions,
                    load_run, scene_tensors, train)

log = logging.getLogger(__name__)

TILE = 256  # sweep-decoder tile side (px): bounds the sweep volume's memory per call


def _as_run(run_or_model) -> Run:
    return run_or_model if isinstance(run_or_model, Run) else load_run(run_or_model)


def _decode_tiled(run: Run, st: dict, i: int, j: int, K_dst: torch.Tensor, w2c_dst: torch.Tensor,
                  hw: tuple[int, int], ctx: torch.Tensor, depths: torch.Tensor,
                  aligned: torch.Tensor | None = None, tile: int = TILE, margin: int = 8) -> torch.Tensor:
    """Sweep-decode one full target image in overlapping tiles (bounded memory). aligned: (2, 3, H, W)
    flow-aligned sources (config ``fallback="flow"``) or None. -> (3, H, W)."""
    h, w = hw
    out = torch.zeros(3, h, w, device=ctx.device)
    src, K, w2c = st["images"][[i, j]], st["K"][[i, j]], st["w2c"][[i, j]]
    for y0 in range(0, h, tile):
        for x0 in range(0, w, tile):
            ya, xa = max(0, y0 - margin), max(0, x0 - margin)
            yb, xb = min(h, y0 + tile + margin), min(w, x0 + tile + margin)
            Kc = K_dst.clone()
            Kc[0, 2] -= xa
            Kc[1, 2] -= ya
            crop = None if aligned is None else aligned[:, :, ya:yb, xa:xb]
            x = sweep_volume(src, K, w2c, Kc, w2c_dst, depths, (yb - ya, xb - xa), crop)
            pred = run.model.decoder(x[None], ctx[None])[0]
            th, tw = min(tile, h - y0), min(tile, w - x0)
            out[:, y0:y0 + th, x0:x0 + tw] = pred[:, y0 - ya:y0 - ya + th, x0 - xa:x0 - xa + tw]
    return out


def _decode_batched(run: Run, st: dict, pairs: list[tuple[int, int]], K_dst: torch.Tensor,
                    w2c_dst: torch.Tensor, hw: tuple[int, int], ctx: torch.Tensor, depths: torch.Tensor,
                    aligned: torch.Tensor | None = None, max_voxels: int = 2 ** 25) -> torch.Tensor:
    """Sweep-decode whole target images several at a time (one decoder call per chunk of targets, the
    chunk bounded by ``max_voxels`` of sweep volume), for images small enough to need no tiling.
    pairs: each target's two source indices; K_dst: (T, 3, 3); w2c_dst: (T, 4, 4); ctx: (T, 512).
    -> (T, 3, H, W). Equal to :func:`_decode_tiled` per target (tested)."""
    h, w = hw
    per = max(1, max_voxels // (len(depths) * h * w))
    out = []
    for a in range(0, len(pairs), per):
        xs = [sweep_volume(st["images"][[i, j]], st["K"][[i, j]], st["w2c"][[i, j]], K_dst[b], w2c_dst[b],
                           depths, hw, None if aligned is None else aligned[b])
              for b, (i, j) in enumerate(pairs[a:a + per], start=a)]
        out.append(run.model.decoder(torch.stack(xs), ctx[a:a + per]))
    return torch.cat(out)


@torch.no_grad()
def synthesize(run_or_model, scene: Scene, targets: list[Frame]) -> np.ndarray:
    """Synthesize the views of ``targets`` from the source frames of ``scene``.

    run_or_model: a :class:`sparself.train.Run` or a run folder / checkpoint path.
    scene: source frames with images (at any resolution: their cameras give the size).
    targets: Frames with pose, camera_id (a camera of ``scene``), fractional index; their images are
    never read. Returns (T, H, W, 3) float32 in [0, 1] at the targets' camera size (all equal).
    """
    run = _as_run(run_or_model)
    if not targets:
        return np.zeros((0, 1, 1, 3), np.float32)
    scene = one_size(scene)
    sizes = {(scene.cameras[t.camera_id].height, scene.cameras[t.camera_id].width) for t in targets}
    if len(sizes) > 1:
        raise InputError(f"targets have different image sizes {sorted(sizes)}; synthesize them separately")
    hw = sizes.pop()
    model = run.model.eval()
    dev = next(model.parameters()).device
    st = scene_tensors(scene)
    st = {k: (v.to(dev) if isinstance(v, torch.Tensor) else v) for k, v in st.items()}
    s = st["images"].shape[0]
    if s < 2:
        raise InputError("need at least 2 source frames to synthesize")
    src_pos = np.arange(s, dtype=np.float64)
    q_pos = index_positions(st["index"], [t.index for t in targets])
    norm = run.norm
    vec = torch.from_numpy(norm.vectors(st["poses"])).to(dev)
    q_vec = torch.from_numpy(norm.vectors([t.pose for t in targets])).to(dev)
    n_before = torch.as_tensor(np.searchsorted(src_pos, q_pos, side="right"), device=dev)
    with autocast(dev, amp_dtype(run.cfg.amp, dev)):
        feats = model.encode(model.backbone_input(st["images"]))
        ctx = model.contexts(feats, vec, torch.tensor(src_pos, dtype=torch.float32, device=dev), q_vec,
                             torch.tensor(q_pos, dtype=torch.float32, device=dev), n_before)
        if run.cfg.decoder == "fc":
            out = F.interpolate(model.decoder(ctx), size=hw, mode="bilinear", align_corners=False)
        else:
            depths = torch.tensor(run.depths, dtype=torch.float32, device=dev)
            pairs = [bracket(src_pos, float(q)) for q in q_pos]
            K_dst = torch.tensor(np.stack([scene.cameras[t.camera_id].K for t in targets]), dtype=torch.float32,
                                 device=dev)
            w2c_dst = torch.tensor(np.stack([t.pose.w2c() for t in targets]), dtype=torch.float32, device=dev)
            aligned = None
            if run.cfg.fallback == "flow":
                aligned = flow_aligned(st["images"], pairs, [bracket_fraction(src_pos, pr, float(q))
                                                             for pr, q in zip(pairs, q_pos)])
            if max(hw) <= TILE:  # small images: all targets through the decoder together
                out = _decode_batched(run, st, pairs, K_dst, w2c_dst, hw, ctx, depths, aligned)
            else:
                out = torch.stack([_decode_tiled(run, st, i, j, K_dst[b], w2c_dst[b], hw, ctx[b], depths,
                                                 None if aligned is None else aligned[b])
                                   for b, (i, j) in enumerate(pairs)])
    return out.float().clamp(0, 1).permute(0, 2, 3, 1).cpu().numpy().astype(np.float32)


def synthesizer(run_or_model):
    """The team synthesizer call ``f(scene, targets) -> (T, H, W, 3)`` bound to a trained run."""
    run = _as_run(run_or_model)
    return lambda scene, targets, **_: synthesize(run, scene, targets)


def densify_scene(scene: Scene, targets: list[Frame], images: np.ndarray) -> Scene:
    """The scene with the synthesized frames added (``image`` set, ``synthetic=True``), ordered by index."""
    if len(targets) != len(images):
        raise ValueError(f"{len(targets)} targets but {len(images)} images")
    new = [replace(t, image=np.asarray(img, np.float32), path=None, synthetic=True)
           for t, img in zip(targets, images)]
    frames = sorted(list(scene.frames) + new, key=lambda f: f.index)
    return replace(scene, frames=frames, meta=dict(scene.meta, synthesized=len(new)))


@dataclass
class DensifyConfig:
    """Options of the whole pipeline. out_size: long side in px of the written scene (None = as read);
    training runs at that size too (``train.size`` is replaced by it)."""

    train: TrainConfig = field(default_factory=TrainConfig)
    plan: object | None = None  # sparself.plan.PlanConfig; None = its defaults
    sfm: object | None = None  # sparself.sfm.SfmConfig; None = its defaults
    out_size: int | None = None
    overwrite: bool = False
    keep_run: bool = True


def _read_input(path: Path, cfg: DensifyConfig) -> Scene:
    """A scene from anything read_scene accepts, else a folder of photos posed with SfM."""
    from . import io as sio

    try:
        sio.detect_format(path)
    except InputError:
        pass  # no pose file here: a folder of photos (list_images/recover_poses say what is wrong with it)
    else:
        return sio.read_scene(path)  # a broken pose file is reported, not silently replaced by SfM
    from .sfm import SfmConfig, recover_poses

    log.info("%s: no poses found; recovering them with structure from motion", path)
    scene, _ = recover_poses(path, cfg.sfm or SfmConfig())  # it logs what was registered and what not
    return scene


def densify(photos_or_scene, out: Path | str, cfg: DensifyConfig | None = None) -> Scene:
    """Photos (or a posed scene) -> poses -> plan -> train -> synthesize -> written dense scene.

    photos_or_scene: a Scene, or a path read by ``sparself.io.read_scene`` or a folder of photos (SfM).
    out: folder written atomically: the dense scene in ``out/scene/`` (``sparself.io.write_scene`` layout:
    images/, sparse/0/, poses_bounds.npy, transforms.json), the plan in ``out/plan.json``, a camera plot
    ``out/cameras.png`` and, if ``keep_run``, the trained run in ``out/run/``. Returns the densified scene.
    """
    from . import io as sio
    from .outputs import check_output_dir
    from .plan import PlanConfig, plan_sequence, save_plan
    from .plot import plot_cameras

    cfg = cfg or DensifyConfig()
    out = Path(out)
    check_output_dir(out, cfg.overwrite)
    scene = photos_or_scene if isinstance(photos_or_scene, Scene) else _read_input(Path(photos_or_scene), cfg)
    if cfg.out_size:
        scene = _materialised(scene.resized(cfg.out_size))
    scene, targets = plan_sequence(scene, cfg.plan or PlanConfig())  # sources on the plan's index scale
    # train at the output resolution: the sweep decoder's windows are in pixels, and training cost depends
    # on the crop size, not on the image size
    long_side = max(max(c.width, c.height) for c in scene.cameras.values())
    tcfg = replace(cfg.train, size=long_side)
    with atomic_dir(out, cfg.overwrite) as tmp:
        run = train(scene, tmp / "run", tcfg)
        images = synthesize(run, scene, targets)
        dense = densify_scene(scene, targets, images)
        sio.write_scene_into(dense, tmp / "scene")
        # the plan and a camera plot beside the scene, so users see where the new views are
        save_plan(tmp / "plan.json", targets, scene=scene, cfg=cfg.plan or PlanConfig())
        plot_cameras(scene, planned=targets, path=tmp / "cameras.png",
                     title=f"{len(scene)} input views (blue) + {len(targets)} synthesized (orange)")
        if not cfg.keep_run:
            import shutil

            shutil.rmtree(tmp / "run")
    return dense


def _materialised(scene: Scene) -> Scene:
    """Frames with their images loaded at the cameras' size (so a resized scene writes resized images)."""
    frames = [replace(f, image=scene.load(i)) for i, f in enumerate(scene.frames)]
    return replace(scene, frames=frames)


def synthesize_plan(run_path: Path | str, plan: Path | str, out: Path | str, *, scene_path: Path | str | None = None,
                    overwrite: bool = False) -> Scene:
    """`sparself synthesize`: the run's scene (minus its holdout) + the plan's poses -> written dense scene."""
    from . import io as sio
    from .outputs import check_output_dir
    from .plan import load_plan, order_frames, reindexed

    check_output_dir(Path(out), overwrite)  # refuse a bad --out before loading anything
    run = load_run(run_path)
    src_path = scene_path or run.meta.get("scene")
    if not src_path:
        raise InputError(f"{run_path}: the run does not record its scene; pass --scene")
    scene = sio.read_scene(Path(src_path))
    hold = set(run.cfg.holdout)
    scene = scene.subset([i for i in range(len(scene)) if i not in hold])
    targets = load_plan(Path(plan), scene)  # validates the file
    order = (json.loads(Path(plan).read_text()).get("config") or {}).get("order")
    if order:  # put the sources on the plan's index scale (it may follow a nearest-neighbour path)
        scene = reindexed(scene, order_frames(scene, order))
    dense = densify_scene(scene, targets, synthesize(run, scene, targets))
    return sio.write_scene(dense, Path(out), overwrite=overwrite)
