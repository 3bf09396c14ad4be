"""Synthesis with a trained CNN–LSTM run: the planned queries, and writing the densified scene.

Novel poses are query steps (pose + fractional index, no image) inserted among all source frames; each
target gets its own sequence (the sources plus its query step), and all targets run as one batch
through :func:`sparself.model.query.render`, the same call training uses.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from sparself.capture import io as sio
from sparself.capture.io.dense import MadeFrom
from sparself.capture.io.dense_photos import DensePhotos
from sparself.capture.scene import Frame, Scene, one_size
from sparself.capture.triangulate import ensure_points
from sparself.core.errors import InputError
from sparself.core.names import check_names
from sparself.core.outputs import Input, check_not_input, check_output_dir, scene_folder, scene_inputs
from sparself.model.query import Sources, flow_aligned, novel_queries, render_with_confidence
from sparself.synthesis.ordering import indices_along, plan_order, reindexed
from sparself.synthesis.plan_files import load_plan, novel_name, plan_source
from sparself.synthesis.run import Run, load_run, recorded_scene, run_scene_mismatch
from sparself.synthesis.train_config import amp_dtype, autocast

log = logging.getLogger(__name__)


def _as_run(run_or_model) -> Run:
    return run_or_model if isinstance(run_or_model, Run) else load_run(run_or_model)


def _target_hw(scene: Scene, targets: list[Frame]) -> tuple[int, int]:
    sizes = {(scene.cameras[t.camera_id].height, scene.cameras[t.camera_id].width) for t in targets}
    if len(sizes) > 1:
        raise InputError(f"targets have different image sizes {sorted(sizes)}; synthesize them separately")
    return sizes.pop()


@dataclass
class Synthesized:
    """Synthesized views (T, H, W, 3) float32 in [0, 1] and their per-pixel confidence (T, H, W) in [0, 1]
    (low where the depth is ambiguous, the sources disagree or the decoder fell back to flow that
    disagrees)."""

    images: np.ndarray
    confidence: np.ndarray
    made_from: list[MadeFrom] = field(default_factory=list)  # per view: the photos that fed it

    def sources_by_name(self, targets: Sequence[Frame]) -> dict[str, MadeFrom]:
        """The photos that fed each view, by the name of its target (what sparself.json records)."""
        return {t.name: m for t, m in zip(targets, self.made_from)}


def synthesize(run_or_model, scene: Scene, targets: list[Frame]) -> np.ndarray:
    """The views of ``targets`` (:func:`synthesize_with_confidence` without the confidence)."""
    return synthesize_with_confidence(run_or_model, scene, targets).images


@torch.no_grad()
def synthesize_with_confidence(run_or_model, scene: Scene, targets: list[Frame]) -> Synthesized:
    """Synthesize the views of ``targets`` from the source frames of ``scene``.

    run_or_model: a :class:`sparself.synthesis.run.Run` or a run folder / checkpoint path.
    scene: source frames with images (at any resolution: their cameras give the size).
    targets: Frames with pose, camera_id (a camera of ``scene``), fractional index; their images are
    never read. Returns images (T, H, W, 3) float32 in [0, 1] at the targets' camera size (all equal),
    and their confidence (T, H, W).
    """
    run = _as_run(run_or_model)
    if not targets:
        return Synthesized(np.zeros((0, 1, 1, 3), np.float32), np.zeros((0, 1, 1), np.float32))
    scene = one_size(scene)
    hw = _target_hw(scene, targets)
    model = run.model.eval()
    dev = next(model.parameters()).device
    sources = Sources.from_scene(scene).to(dev).posed(run.norm, run.depths)
    queries = novel_queries(
        sources,
        np.stack([scene.cameras[t.camera_id].K for t in targets]),
        np.stack([t.pose.w2c() for t in targets]),
        run.norm.vectors([t.pose for t in targets]),
        [t.index for t in targets],
        hw,
        run.cfg.sources,
    )
    if run.uses_flow():
        queries = flow_aligned(sources, queries)
    with autocast(dev, amp_dtype(run.cfg.amp, dev)):
        out, conf = render_with_confidence(model, sources, queries)
    names = tuple(scene.frames[int(i)].name for i in sources.order)
    return Synthesized(
        out.float().clamp(0, 1).permute(0, 2, 3, 1).cpu().numpy().astype(np.float32),
        conf.float().clamp(0, 1)[:, 0].cpu().numpy().astype(np.float32),
        [MadeFrom(tuple(names[int(j)] for j in s), names) for s in queries.sets],
    )


def synthesizer(run_or_model):
    """The synthesizer call every method shares, ``f(scene, targets) -> (T, H, W, 3)``, bound to a trained run."""
    run = _as_run(run_or_model)
    return lambda scene, targets, **_: synthesize(run, scene, targets)


def densify_scene(
    scene: Scene, targets: list[Frame], images: np.ndarray, confidence: np.ndarray | None = None
) -> Scene:
    """The scene with the synthesized frames added (``image`` set, ``synthetic=True``, and ``confidence``
    (T, H, W) when given: written as ``masks/``), ordered by index."""
    if len(targets) != len(images):
        raise ValueError(f"{len(targets)} targets but {len(images)} images")
    confs = [None] * len(targets) if confidence is None else list(confidence)
    new = [
        replace(t, image=np.asarray(img, np.float32), path=None, synthetic=True, confidence=c)
        for t, img, c in zip(targets, images, confs)
    ]
    frames = sorted(list(scene.frames) + new, key=lambda f: f.index)
    return replace(scene, frames=frames)


def _check_order(run_path: Path, plan: Path) -> None:
    """A plan file given as RUN (and a run folder as --plan): say so instead of 'no checkpoint'."""
    if run_path.is_file() and run_path.suffix.lower() == ".json" and plan.is_dir():
        raise InputError(
            f"{run_path}: is a plan file and {plan} a run folder: the arguments are swapped "
            f"(sparself synthesize {plan} --plan {run_path} --out ...)"
        )
    if run_path.is_file() and run_path.suffix.lower() == ".json":
        raise InputError(
            f"{run_path}: is a plan file, not a run folder (sparself synthesize RUN --plan {run_path} --out ...)"
        )


def synthesize_plan(
    run_path: Path | str,
    plan: Path | str,
    out: Path | str,
    *,
    scene_path: Path | str | None = None,
    overwrite: bool = False,
    downscaled: bool = True,
    triangulate: bool = True,
) -> Scene:
    """`sparself synthesize`: the run's scene (minus its holdout) + the plan's poses -> written dense scene.
    A dense scene sparself wrote (``densify``'s ``OUT/scene``) is read as the capture it was made from (its
    photos, named and indexed as the run knew them: :mod:`sparself.capture.io.dense_photos`), and a plan made
    on it is mapped to the capture's index scale.
    downscaled: also write the ``images_2/4/8`` copies; triangulate: a scene without sparse points gets
    points triangulated from its real photos (:func:`sparself.capture.triangulate.ensure_points`)."""
    _check_order(Path(run_path), Path(plan))
    inputs = [Input("run folder", run_path), Input("plan file", plan), Input("scene", scene_path)]
    check_not_input(Path(out), inputs)
    run = load_run(run_path)
    src = Path(scene_path) if scene_path else recorded_scene(run.meta, run.path or Path(run_path))
    check_not_input(Path(out), [Input("run's scene", scene_folder(src))])
    scene = sio.read_scene(src)
    check_output_dir(Path(out), overwrite, scene_inputs(scene, "run's scene"))  # before any synthesis
    photos = sio.read_dense_photos(scene, src)
    holdout = run.cfg.holdout
    if photos is not None:  # its synthesized views are never sources; its photos get their own names back
        scene, holdout = photos.scene, tuple(photos.held_out(run.cfg.holdout, len(run.meta.sources)))
        log.info("%s: a dense scene: synthesizing from its %d photos", src, len(scene))
    why = run_scene_mismatch(run.meta, scene, holdout)
    if why:
        raise InputError(f"{scene.source}: not the scene the run {run_path} was trained on ({run.meta.scene}): {why}")
    targets, order = _planned(Path(plan), scene, photos)  # validated, and made for this scene
    scene = scene.without(holdout)
    check_names([t.name for t in targets], plan, what="frame name", taken=[f.name for f in scene.frames])
    if order:  # put the sources on the plan's index scale (it may follow a nearest-neighbour path)
        scene = reindexed(scene, plan_order(scene, order))
    syn = synthesize_with_confidence(run, scene, targets)
    written = ensure_points(scene) if triangulate else scene
    dense = densify_scene(written, targets, syn.images, syn.confidence)
    info = sio.DenseInfo(str(run_path), str(plan), downscale=downscaled, made_from=syn.sources_by_name(targets))
    return sio.write_scene(dense, Path(out), overwrite=overwrite, dense=info)


def _planned(plan: Path, scene: Scene, photos: DensePhotos | None) -> tuple[list[Frame], str | None]:
    """The plan's frames on ``scene``'s index scale, and the order its sources follow (None: as they are).
    A plan made on a dense scene (``sparself plan OUT/scene``) counts its synthesized frames too: its
    indices are mapped to the run's through the recorded indices of the written frames."""
    made_on = plan_source(plan)
    if photos is None or not photos.made_for_dense(made_on.names, made_on.n_views):
        return load_plan(plan, scene), made_on.order
    targets = load_plan(plan, photos.dense)
    seq = plan_order(photos.dense, made_on.order or "capture")
    if not np.array_equal(indices_along(photos.dense, seq), [photos.dense.frames[i].index for i in seq]):
        raise InputError(
            f"{plan}: made on the dense scene {photos.record.parent} along a nearest-neighbour path, whose "
            "indices do not map to the capture's; make it with --order capture"
        )
    mapped = []
    for t in targets:
        k = photos.capture_index(t.index)
        mapped.append(replace(t, index=k, name=novel_name(k) if t.name == novel_name(t.index) else t.name))
    return mapped, None
