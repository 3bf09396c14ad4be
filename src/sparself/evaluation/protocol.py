"""The held-out evaluation protocol: does densifying a sparse capture with synthesized views help?

Protocol (per scene, in this order):

1. **Hold out** evaluation frames before anything else: every ``holdout_every``-th frame (default 8),
   interior ones only (never the first or last frame, so they are interpolations, as LLFF's
   ``llffhold`` split but without frame 0). Only their *poses* leave this module's scoring step;
   their pixels are decoded in :func:`load_truth`, called only while scoring.
2. **Dense captures** (enough frames left for at least one real photo in every gap between the N
   inputs): an *extrapolation margin* of frames is kept beyond each end (``extrapolation_margin``; auto:
   one input spacing, at least ``holdout_every + 1`` frames so a held-out frame lies beyond each end;
   0: none), and N evenly spaced frames of the rest inside the margins are the sparse input (N = 25 by
   default). Margin frames are never inputs. The planned midpoints (sparself.synthesis.plan, 8 by default) are
   *snapped* to the real frame nearest the planned index in their gap, and the extrapolated poses
   (t = 1.2, 2 by default) to the margin frame nearest the planned index beyond the same end input, so
   each has a real photo at exactly its pose: the ground truth for view synthesis at planned poses
   (``midpoints`` and ``extrapolations``), and the oracle's training image.
3. **Sparse captures** (too few frames, e.g. 16-view Middlebury rings): every other interior frame is
   held out and the rest are the inputs. No real photos lie between inputs except held-out ones, so no
   oracle is run and midpoints are not scored separately (the held-out frames are the midpoints).
4. **Sparse points** (``points``): the capture's own points were made from all its photos, held-out ones
   included, so by default they are dropped and points are triangulated from the N inputs' photos at their
   known poses (:func:`input_points`, sparself.capture.triangulate), before anything is fitted. Every row of a
   scene (N, N + synthesized, weighted, oracle) and the network's and baselines' depth range start from
   these same points. ``points="capture"`` keeps the capture's points (runs before this option).
5. Two questions:
   - *View synthesis*: the network (``seeds`` seeds) and every baseline synthesize the held-out
     poses from the inputs alone; scored against the real photos. Held-out frames beyond the first or
     last input (in the margins) are *extrapolated*, the others *interpolated*: every score is also
     summarised per group (``groups``, where a set has both).
   - *Densification*: each reconstructor is fitted on the N inputs ("25"), on N + synthesized views
     ("35", network per seed and each densify-baseline), and on the oracle (N + real photos at the
     snapped planned poses; a planned pose without one keeps the network's seed-0 view), then renders the held-out
     poses. The oracle share is (35 - 25) / (oracle - 25) in PSNR.

"N + sparself, weighted" (``weighted``, on by default) refits each reconstructor on N + the network's views
with their confidence maps as per-pixel loss weights, times a synthetic-frame weight chosen from
``synthetic_weights`` on the inputs alone (:func:`choose_weight`: fitted without every 5th interior input,
scored on those), on the run's first seed; the plain "N + sparself" stays unweighted, for comparability.
The validation fits' synthesized views are synthesized again by that seed's network from the inputs minus
the held-back ones (:func:`validation_views`), so their pixels carry none of the held-back photos; the
network itself was still trained on all inputs (retraining per choice would be too slow).

Results: a :class:`~sparself.evaluation.scene_results.SceneResult` (per frame, per scene, mean/std); a
scene that fails is recorded with its error and the others go on (:mod:`sparself.evaluation.evaluate`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm.auto import tqdm

from sparself.capture.plot import plot_cameras
from sparself.capture.scene import MIN_POINTS, Frame, Scene, points_depth_range, preloaded
from sparself.capture.triangulate import triangulate, with_points
from sparself.core.errors import InputError, SparselfError
from sparself.core.geometry import rotation_angle_deg
from sparself.evaluation.config import PLANNED_SECTIONS, EvalConfig, PlannedSection
from sparself.evaluation.densification import densification
from sparself.evaluation.instruments import (
    SynthFn,
    baseline_fns,
    images_and_confidence,
    network_factory,
)
from sparself.evaluation.report_context import safe_name as _safe
from sparself.evaluation.results import (
    AT_VIEWS,
    EXTRAPOLATED,
    INTERPOLATED,
    NETWORK,
    RowError,
    ScoredSet,
    SeededSets,
)
from sparself.evaluation.scene_eval import SceneEval, pose_only
from sparself.evaluation.scene_results import CameraFrames, InputPoints, PlannedPose, SceneResult, SplitInfo
from sparself.evaluation.split import HeldOutSplit, make_split
from sparself.recon import Renderer
from sparself.synthesis.plan import PlanConfig, plan_poses

log = logging.getLogger(__name__)


def snap(index: float, split: HeldOutSplit) -> int | None:
    """The real frame a planned pose at ``index`` is snapped to on a dense capture: a midpoint to the
    ``between`` frame nearest it in its gap, an extrapolation to the ``margin`` frame nearest it beyond
    the same end input; None when there is none (or on a sparse capture)."""
    if split.kind != "dense":
        return None
    lo = max([i for i in split.inputs if i <= index], default=None)
    hi = min([i for i in split.inputs if i >= index], default=None)
    if lo is None:
        cands = [i for i in split.margin if i < split.inputs[0]]
    elif hi is None:
        cands = [i for i in split.margin if i > split.inputs[-1]]
    else:
        cands = [i for i in split.between if lo < i < hi]
    return min(cands, key=lambda i: (abs(i - index), i)) if cands else None


def plan(inputs: Scene, split: HeldOutSplit, cfg: EvalConfig, full: Scene) -> tuple[list[Frame], list[PlannedPose]]:
    """Planned novel frames (pose only) and how each relates to a real photo (dense: snapped midpoints and
    extrapolations)."""
    planned = plan_poses(inputs, PlanConfig(n_mid=cfg.n_mid, n_extra=cfg.n_extra, order="capture"))
    info: list[PlannedPose] = []
    out: list[Frame] = []
    for f in planned:
        rec = PlannedPose(f.name, f.index, split.group(f.index))
        j = snap(f.index, split)
        if j is not None:
            real = full.frames[j]
            rec.truth, rec.truth_name = j, real.name
            rec.snap_move = float(np.linalg.norm(real.pose.center - f.pose.center) / full.scale())
            rec.snap_turn_deg = float(rotation_angle_deg(real.pose.R, f.pose.R))
            f = pose_only(real, name=f"novel_at_{real.name}", synthetic=True)
        out.append(f)
        info.append(rec)
    return out, info


def scene_name(scene: Scene) -> str:
    """The capture's folder name (a pose file's folder: ``middlebury_dinoSparseRing``, not ``dinoSR_par.txt``)."""
    if scene.source is None:
        return "scene"
    return name_from_source(scene.source)


def name_from_source(source: str | Path) -> str:
    """``.../llff_bird/sparse/0`` -> ``llff_bird``; ``.../dino/dinoSR_par.txt`` -> ``dino``."""
    src = Path(source)
    if src.suffix:
        src = src.parent
    while (src.name.isdigit() or src.name == "sparse") and src.parent != src:
        src = src.parent
    return src.name


def sorted_resized(scene: Scene, cfg: EvalConfig) -> Scene:
    """The capture in index order at the evaluation's size, re-indexed 0..n-1."""
    order = sorted(range(len(scene)), key=lambda i: scene.frames[i].index)
    full = scene.subset(order).resized(cfg.size)
    return replace(full, frames=[replace(f, index=float(k)) for k, f in enumerate(full.frames)])


def input_points(full: Scene, cameras: dict, inputs: list[int], cfg: EvalConfig, res: SceneResult) -> Scene:
    """``full`` with its sparse points set by ``cfg.points``, recorded in ``res.input_points``.

    "inputs": triangulated from the photos of frames ``inputs`` alone (at their original ``cameras``, up to
    800 px), never a held-out one; fewer than MIN_POINTS are dropped (the reconstructors then fall back as on a
    capture without points; noted), their depth range kept as the scene's bounds where it has none.
    "capture": the capture's own points. Called before anything is fitted: ``ev.inputs`` inherits these
    points, and every row of the scene (N, N + sparself, weighted, densify baselines, oracle) fits on
    ``ev.inputs`` plus frames, so all rows share the same points."""
    if cfg.points == "capture":
        res.input_points = InputPoints("capture", 0 if full.points is None else len(full.points))
        return full
    tri = triangulate(replace(full.subset(inputs), cameras=cameras))
    res.input_points = InputPoints("inputs", len(tri.points), tri.views, tri.pairs, tri.matches, tri.seconds)
    if len(tri.points) < MIN_POINTS:
        # too few to start from, enough to bound the depth (a guess from the camera layout is far off)
        seen = points_depth_range(tri.points, [full.frames[i].pose for i in inputs])
        bounds = full.bounds or seen
        res.notes.append(
            f"{len(tri.points)} points triangulated from the inputs (< {MIN_POINTS}): none used, "
            "the reconstructors start without sparse points"
            + (f"; their depth range {seen[0]:.3g}..{seen[1]:.3g} bounds the scene" if seen and not full.bounds else "")
        )
        return replace(full, points=None, point_colors=None, observations={}, bounds=bounds)  # the capture's
    return with_points(full, tri)


def protocol(ev: SceneEval, plan_info: list[PlannedPose]) -> SplitInfo:
    """What the report says about the split, and the cameras for its plot."""
    full, split = ev.full, ev.split
    return SplitInfo(
        kind=split.kind,
        rule=split.rule,
        n_frames=len(full),
        held_out=[full.frames[i].name for i in split.eval],
        held_out_index=split.eval,
        scored=[full.frames[i].name for i in ev.scored],
        inputs=[full.frames[i].name for i in split.inputs],
        inputs_index=split.inputs,
        extrapolated=[full.frames[i].name for i in ev.scored if split.group(i) == EXTRAPOLATED],
        margin=[full.frames[i].name for i in split.margin],
        image_size=list(full.image_size(0)),
        planned=plan_info,
        camera_frames=CameraFrames(
            [f.pose.as_vector().tolist() for f in ev.inputs.frames],
            [f.pose.as_vector().tolist() for f in ev.targets],
            [f.pose.as_vector().tolist() for f in ev.planned],
        ),
    )


def run_name(capture: str, cfg: EvalConfig, n_inputs: int) -> str:
    """A run's name in the results: the capture's, with its N when the run sweeps several."""
    return capture if len(cfg.inputs) == 1 else f"{capture} N={n_inputs}"


def start_scene(scene: Scene, cfg: EvalConfig, out_dir: Path | None, n_inputs: int | None = None) -> SceneEval:
    """HeldOutSplit the capture (``n_inputs`` inputs, None: the largest of ``cfg.inputs``), plan the novel poses and
    draw the cameras."""
    n_inputs = n_inputs or max(cfg.inputs)
    capture = scene_name(scene)
    name = run_name(capture, cfg, n_inputs)
    res = SceneResult(name, capture, n_inputs, str(scene.source) if scene.source else None)
    full = sorted_resized(scene, cfg)
    split = make_split(len(full), cfg, n_inputs)
    if len(split.eval) == 0:
        raise InputError(f"{name}: {len(full)} frames leave no interior frame to hold out")
    full = input_points(full, scene.cameras, split.inputs, cfg, res)
    scored = split.eval
    if cfg.max_eval and len(scored) > cfg.max_eval:
        scored = [scored[p] for p in np.round(np.linspace(0, len(scored) - 1, cfg.max_eval)).astype(int)]
    inputs = preloaded(full.subset(split.inputs))
    planned, plan_info = plan(inputs, split, cfg, full)
    mid_truth = {k: rec.truth for k, rec in enumerate(plan_info) if rec.truth is not None}
    ev = SceneEval(name, cfg, full, split, scored, inputs, planned, mid_truth, res, out_dir)
    res.split = protocol(ev, plan_info)
    at = ev.at_views(planned)
    if at.any():
        res.notes.append(
            f"{AT_VIEWS}{int(at.sum())} of {len(at)} scored held-out frames lie at a planned view's pose (within "
            "a quarter of the inputs' spacing; the rows with every view)"
        )
    if out_dir is not None and cfg.examples > 0:
        ev.ex_dir = Path(out_dir) / "examples" / _safe(name)
        ev.ex_dir.mkdir(parents=True, exist_ok=True)
        camera_plot(inputs, planned, [pose_only(full.frames[i]) for i in split.eval], ev.ex_dir / "cameras.png", name)
        res.camera_plot = str((ev.ex_dir / "cameras.png").relative_to(out_dir))
    return ev


def planned_scores(
    ev: SceneEval, images: np.ndarray, label: str, seed: int | None = None
) -> dict[PlannedSection, ScoredSet]:
    """The planned views that have a real photo at their pose, scored: {"midpoints": ..., "extrapolations":
    ...} (a set only where it has frames)."""
    if not ev.mid_truth:
        return {}
    scored = ev.score(images[list(ev.mid_truth)], label, ev.mid_targets, held_out=False, seed=seed)
    sets: dict[PlannedSection, ScoredSet] = {
        "midpoints": scored.only(INTERPOLATED),
        "extrapolations": scored.only(EXTRAPOLATED),
    }
    return {k: v for k, v in sets.items() if v.frames}


def network_synthesis(ev: SceneEval, network: Callable[[Scene, int], SynthFn] | None) -> None:
    """Train the network per seed on the inputs; score it at the held-out poses and the planned poses
    with a real photo (midpoints and extrapolations)."""
    if network is None:
        try:
            network = network_factory(ev.cfg)
        except SparselfError as e:
            ev.result.notes.append(str(e))
            return
    held, planned = SeededSets(), {sec: SeededSets() for sec in PLANNED_SECTIONS}
    for seed in tqdm(ev.cfg.seed_list, desc=f"{ev.name}: network seeds", disable=not ev.cfg.progress, leave=False):
        synth = network(ev.inputs, seed)
        ev.net_synths.append(synth)
        imgs, conf = images_and_confidence(synth(ev.inputs, ev.targets))
        ev.net_targets.append((imgs, conf))
        held.per_seed.append(ev.score(imgs, f"{NETWORK} seed {seed}" if seed else NETWORK, ev.scored, seed=seed))
        imgs, conf = images_and_confidence(synth(ev.inputs, ev.planned))
        ev.net_planned.append(imgs)
        ev.net_conf.append(conf)
        for sec, scored in planned_scores(ev, imgs, NETWORK, seed).items():
            planned[sec].per_seed.append(scored)
    vs = ev.result.synthesis
    vs.held_out[NETWORK] = held
    for sec, sets in planned.items():
        if sets.per_seed:
            vs.planned(sec)[NETWORK] = sets


def baseline_synthesis(ev: SceneEval, baselines: dict[str, SynthFn]) -> None:
    """Each baseline at the held-out poses and the planned poses with a real photo (and the planned poses
    it densifies)."""
    vs = ev.result.synthesis
    for bname, fn in tqdm(
        list(baselines.items()), desc=f"{ev.name}: baselines", disable=not ev.cfg.progress, leave=False
    ):
        try:
            vs.held_out[bname] = ev.score(fn(ev.inputs, ev.targets), bname, ev.scored)
            if bname in ev.cfg.densify_baselines or ev.mid_truth:
                ev.baseline_planned[bname] = fn(ev.inputs, ev.planned)
                for sec, scored in planned_scores(ev, ev.baseline_planned[bname], bname).items():
                    vs.planned(sec)[bname] = scored
        except Exception as e:  # one broken baseline must not hide the others
            log.warning("%s: baseline %s failed: %s", ev.name, bname, e)
            vs.held_out[bname] = RowError(f"{type(e).__name__}: {e}")


def evaluate_scene(
    scene: Scene,
    cfg: EvalConfig,
    out_dir: Path | None = None,
    *,
    network: Callable[[Scene, int], SynthFn] | None = None,
    reconstructors: dict[str, Callable[[Scene], Renderer]] | None = None,
    baselines: dict[str, SynthFn] | None = None,
    on_partial: Callable[[SceneResult], None] | None = None,
    n_inputs: int | None = None,
) -> SceneResult:
    """Run the protocol on one scene with ``n_inputs`` inputs (one of ``cfg.inputs``; None: the largest).
    Returns the scene's results.

    network: ``make(inputs_scene, seed) -> synthesize`` (default: :func:`network_factory`); None when
    unavailable is recorded. ``synthesize(sources, targets)`` gets the inputs as sources, and for the
    weighted row's weight choice (first seed) the inputs minus :func:`validation_inputs`.
    reconstructors / baselines: override the registries (tests).
    out_dir: where example images are saved (``examples/<scene>/``); None saves none.
    on_partial: called with the results so far after the network, the baselines and each reconstructor
    (long runs can save what they have).
    """
    t_start = time.perf_counter()
    ev = start_scene(scene, cfg, out_dir, n_inputs)
    ev.on_partial = on_partial
    res = ev.result
    t0 = time.perf_counter()
    network_synthesis(ev, network)
    res.timings.network = time.perf_counter() - t0
    ev.partial()
    t0 = time.perf_counter()
    baseline_synthesis(ev, baselines if baselines is not None else baseline_fns(cfg.baselines))
    res.timings.baselines = time.perf_counter() - t0
    ev.partial()
    densification(ev, reconstructors)
    res.status = "ok"
    res.timings.total = time.perf_counter() - t_start
    return res


def camera_plot(inputs: Scene, planned: list[Frame], held: list[Frame], path: Path, name: str) -> None:
    try:
        plot_cameras(inputs, planned, held, path=path, title=f"{name}: inputs, planned (synthesized), held-out")
    except Exception as e:  # a missing plot is not worth failing the evaluation
        log.warning("camera plot failed: %s", e)
