"""The held-out evaluation protocol: does densifying a sparse capture with synthesized views help?

Protocol (per scene, in this order):

1. **Hold out** evaluation frames before anything else: every ``holdout_every``-th frame (default 8),
   interior ones only (never the first or last frame, so they are interpolations, as LLFF's
   ``llffhold`` split but without frame 0). Only their *poses* leave this module's scoring step;
   their pixels are decoded in :func:`_load_truth`, called only while scoring.
2. **Dense captures** (enough frames left for at least one real photo in every gap between the N
   inputs): an *extrapolation margin* of frames is kept beyond each end (``extrapolation_margin``; auto:
   one input spacing, at least ``holdout_every + 1`` frames so a held-out frame lies beyond each end;
   0: none), and N evenly spaced frames of the rest inside the margins are the sparse input (N = 25 by
   default). Margin frames are never inputs. The planned midpoints (sparself.plan, 8 by default) are
   *snapped* to the real frame nearest the planned index in their gap, and the extrapolated poses
   (t = 1.2, 2 by default) to the margin frame nearest the planned index beyond the same end input, so
   each has a real photo at exactly its pose: the ground truth for view synthesis at planned poses
   (``midpoints`` and ``extrapolations``), and the oracle's training image.
3. **Sparse captures** (too few frames, e.g. 16-view Middlebury rings): every other interior frame is
   held out and the rest are the inputs. No real photos lie between inputs except held-out ones, so no
   oracle is run and midpoints are not scored separately (the held-out frames are the midpoints).
4. **Sparse points** (``points``): the capture's own points were made from all its photos, held-out ones
   included, so by default they are dropped and points are triangulated from the N inputs' photos at their
   known poses (:func:`input_points`, sparself.triangulate), before anything is fitted. Every row of a
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

Results: a JSON-able dict (per frame, per scene, mean/std, every setting and versions). A scene that
fails is recorded with its error and the others go on.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import platform
import subprocess
import tempfile
import time
import traceback
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from tqdm.auto import tqdm

from . import metrics
from .baselines import BASELINES
from .errors import ConfigError, InputError, SparselfError
from .geometry import rotation_angle_deg
from .io import read_scene
from .model import default_weights
from .options import option
from .outputs import Input, atomic_dir, check_not_input, evaluation_inputs
from .plan import PlanConfig, plan_poses
from .plot import plot_cameras
from .recon import get_reconstructor
from .report import safe_name as _safe
from .report import write_report
from .results import (EXTRAPOLATED, INTERPOLATED, NETWORK, NETWORK_WEIGHTED, FrameScore, ScoredSet, SeededSets,
                      share_of_oracle_gain)
from .scene import MIN_POINTS, Frame, Scene, load_image, preloaded, resize_image, save_image
from .synthesize import Synthesized, densify_scene, synthesize_with_confidence
from .train import TrainConfig, train
from .triangulate import triangulate, with_points

log = logging.getLogger(__name__)

# synthesize(scene, targets) -> (T, H, W, 3), or Synthesized (images + per-pixel confidence)
SynthFn = Callable[[Scene, list], "np.ndarray | Synthesized"]
DIETNERF_NOTE = "not run: DietNeRF needs CLIP weights that cannot be fetched here (no internet)"
PLANNED_SECTIONS = ("midpoints", "extrapolations")  # results of the planned views that have a real photo
POINTS_CHOICES = ("inputs", "capture")  # where the inputs' sparse points come from (EvalConfig.points)
VALIDATION_EVERY = 5  # every 5th interior input view is held back to choose the synthetic-frame weight


# what --quick changes
QUICK = dict(size=64, seeds=1, nerf_steps=300, max_eval=6, densify_baselines=("blend",), epochs=3)


@dataclass
class EvalConfig:
    """Every setting of an evaluation run (all recorded in the results; each field's help is its
    documentation, and ``sparself evaluate --help`` shows them). ``train``: the network's training options
    (its seed, size and epochs are set by the evaluation)."""

    size: int = option(128, "longer image side in pixels for every step (images are resized once, on load)")
    inputs: int = option(25, "N, the number of sparse input views taken from a dense capture")
    extrapolation_margin: int | None = option(
        None, "capture frames kept beyond the first and last input of a dense capture (never inputs): their real "
        "photos score extrapolated views; auto: one input spacing, at least holdout_every + 1 so held-out frames "
        "lie beyond both ends; 0: the inputs span the whole capture")
    holdout_every: int = option(8, "hold out every k-th interior frame of a dense capture")
    sparse_holdout_every: int = option(2, "the same for captures too small for the dense protocol")
    n_mid: int = option(8, "planned midpoints used for densification")
    n_extra: int = option(2, "planned extrapolated poses used for densification")
    seeds: int = option(3, "network seeds, reported as mean ± std")
    first_seed: int = option(0, "the first network seed: seeds are first_seed .. first_seed + seeds - 1 (`sparself "
                                "batch evaluate` runs one seed per task)")
    reconstructors: tuple[str, ...] = option(("mpi", "nerf"), "reconstructors, comma-separated: mpi,nerf,gsplat,3dgs",
                                             flag="--recon")
    baselines: tuple[str, ...] = option(("nearest", "blend", "flow", "planesweep"),
                                        "view-synthesis baselines scored on held-out poses")
    densify_baselines: tuple[str, ...] = option(("blend", "flow", "planesweep"),
                                                "baselines whose synthesized views are also used for densification")
    epochs: int | None = option(None, "network training epochs (auto: the network's)")
    nerf_steps: int = option(1000, "NeRF optimisation steps per fit")
    recon_seed: int = option(0, "seed of the reconstructors")
    max_eval: int | None = option(None, "score at most this many held-out frames per scene (evenly chosen; "
                                  "auto: all)")
    oracle: bool = option(True, "skip the oracle densification (real photos at the planned poses)")
    weighted: bool = option(True, "skip 'N + sparself, weighted': each reconstructor refitted on N + the network's "
                                  "views with their confidence maps as per-pixel loss weights and a synthetic-frame "
                                  "weight chosen on input views only")
    synthetic_weights: tuple[float, ...] = option(
        (0.25, 0.5, 1.0), "synthetic-frame loss weights tried for 'N + sparself, weighted': each is fitted on the "
        f"inputs minus every {VALIDATION_EVERY}th interior one (+ the first seed's views), the best PSNR on those "
        "held-back inputs wins (one fit per weight and reconstructor, plus one refit per seed)")
    examples: int = option(1, "held-out frames per scene saved as image grids for the report")
    lpips: bool = option(True, "skip LPIPS")
    points: str = option("inputs", "the inputs' sparse points (3DGS initial Gaussians, NeRF's scene box, the depth "
                         "range of scenes without bounds): 'inputs' triangulates them from the N inputs' photos at their "
                         "known poses (the capture's own points, made from every photo, held-out ones included, are "
                         "dropped); 'capture' keeps the capture's points (as runs before this option)",
                         choices=POINTS_CHOICES)
    progress: bool = option(True, "progress bars", cli=False)
    train: TrainConfig = field(default_factory=TrainConfig)

    def validate(self) -> None:
        if self.size < 8:
            raise ConfigError(f"size must be at least 8 pixels, got {self.size}")
        if self.inputs < 3:
            raise ConfigError(f"inputs must be at least 3, got {self.inputs}")
        if self.holdout_every < 2 or self.sparse_holdout_every < 2:
            raise ConfigError("holdout_every and sparse_holdout_every must be at least 2")
        if self.seeds < 1:
            raise ConfigError(f"seeds must be at least 1, got {self.seeds}")
        if self.first_seed < 0:
            raise ConfigError(f"first_seed must not be negative, got {self.first_seed}")
        if self.extrapolation_margin is not None and self.extrapolation_margin < 0:
            raise ConfigError(f"extrapolation_margin must not be negative, got {self.extrapolation_margin}")
        if self.points not in POINTS_CHOICES:
            raise ConfigError(f"points must be one of {', '.join(POINTS_CHOICES)}, got {self.points!r}")
        if self.weighted and (not self.synthetic_weights or min(self.synthetic_weights) < 0):
            raise ConfigError(f"synthetic_weights must be one or more weights >= 0, got {self.synthetic_weights}")

    @classmethod
    def quick(cls, **kw) -> "EvalConfig":
        """Minutes, not hours, on 2 CPU cores: 64 px, 1 seed, 3 network epochs (an under-trained network),
        a short NeRF, at most 6 scored frames, one baseline densified."""
        base = dict(QUICK)
        base.update(kw)
        return cls(**base)


# ---- the split -------------------------------------------------------------------------------------

def holdout_indices(n: int, every: int = 8) -> list[int]:
    """Interior frames every ``every`` frames: k*every for 0 < k*every < n - 1.

    >>> holdout_indices(20, 8)
    [8, 16]
    """
    return list(range(every, n - 1, every))


def evenly_spaced(indices: Sequence[int], n: int) -> list[int]:
    """n items of ``indices`` evenly spread from first to last (all of them if n >= len)."""
    indices = list(indices)
    if n >= len(indices):
        return indices
    pos = np.round(np.linspace(0, len(indices) - 1, n)).astype(int)
    return [indices[p] for p in pos]


def gap_truth(available: Sequence[int], inputs: Sequence[int]) -> list[int | None]:
    """For each gap between consecutive inputs, the available frame nearest the gap's midpoint
    strictly inside it (ties: the earlier), or None. ``available`` excludes held-out and input frames."""
    avail = sorted(available)
    out: list[int | None] = []
    for a, b in zip(inputs[:-1], inputs[1:]):
        inside = [i for i in avail if a < i < b]
        mid = (a + b) / 2.0
        out.append(min(inside, key=lambda i: (abs(i - mid), i)) if inside else None)
    return out


@dataclass
class Split:
    """Which frame (by position in capture order) plays which role.

    kind: "dense" or "sparse". eval: held-out frames. inputs: sparse input frames.
    between: frames between the first and last input, neither held out nor input (real photos usable as
    midpoint truth / oracle). margin: frames beyond the first and last input, not held out (real photos
    usable as extrapolation truth / oracle; never inputs). rule: the protocol in words, for the report.
    """

    kind: str
    eval: list[int]
    inputs: list[int]
    between: list[int]
    rule: str
    margin: list[int] = field(default_factory=list)

    def group(self, i: int) -> str:
        """EXTRAPOLATED for a frame beyond the first or last input in capture order, else INTERPOLATED."""
        return EXTRAPOLATED if i < self.inputs[0] or i > self.inputs[-1] else INTERPOLATED


def extrapolation_margin(n: int, cfg: EvalConfig) -> int:
    """Frames kept beyond each end input: the setting, or auto: one input spacing ((n-1)/(N+1) frames),
    at least holdout_every + 1 so that a held-out frame lies beyond each end."""
    if cfg.extrapolation_margin is not None:
        return cfg.extrapolation_margin
    return max(round((n - 1) / (cfg.inputs + 1)), cfg.holdout_every + 1)


def _dense_split(n: int, held: list[int], rest: list[int], cfg: EvalConfig) -> Split:
    """N inputs evenly spaced over the frames inside the extrapolation margins (all of them if too few)."""
    m = extrapolation_margin(n, cfg)
    inside = [i for i in rest if m <= i <= n - 1 - m]
    dropped = ""
    if m and len(inside) < 2 * cfg.inputs - 1:
        dropped = f" (too few frames for a {m}-frame extrapolation margin)"
        m, inside = 0, rest
    inputs = evenly_spaced(inside, cfg.inputs)
    between = [i for i in rest if inputs[0] < i < inputs[-1] and i not in set(inputs)]
    margin = [i for i in rest if i < inputs[0] or i > inputs[-1]]
    beyond = [i for i in held if i < inputs[0] or i > inputs[-1]]
    rule = (f"dense: every {cfg.holdout_every}th interior frame held out ({len(held)}); {len(inputs)} evenly "
            f"spaced inputs from the {len(inside)} remaining frames {inside[0]}..{inside[-1]}{dropped}; ")
    if margin:
        rule += (f"the {len(margin)} real frames beyond the first and last input (an extrapolation margin of {m} "
                 f"frames, never inputs) are ground truth for extrapolated poses and the oracle, and the "
                 f"{len(beyond)} held-out frames there are scored as extrapolations; ")
    rule += f"the other {len(between)} real frames are ground truth for midpoint poses and the oracle"
    return Split("dense", held, inputs, between, rule, margin)


def make_split(n: int, cfg: EvalConfig) -> Split:
    """The protocol's split of a capture of n frames (see the module docstring)."""
    held = holdout_indices(n, cfg.holdout_every)
    rest = [i for i in range(n) if i not in set(held)]
    if len(rest) >= 2 * cfg.inputs - 1:
        return _dense_split(n, held, rest, cfg)
    held = list(range(1, n - 1, cfg.sparse_holdout_every))  # second, fourth, ...: the ends stay inputs
    inputs = [i for i in range(n) if i not in set(held)]
    rule = (f"sparse: too few frames for {cfg.inputs} inputs with real frames between them; every "
            f"{cfg.sparse_holdout_every}nd interior frame from the second on held out ({len(held)}), the other {len(inputs)} "
            "are the inputs; no oracle (the only real frames between inputs are the held-out ones)")
    return Split("sparse", held, inputs, [], rule)


# ---- helpers ---------------------------------------------------------------------------------------

def _pose_only(f: Frame, **kw) -> Frame:
    """A copy of f with no pixels attached: what synthesizers and renderers may see of a held-out frame."""
    return replace(f, path=None, image=None, **kw)


def _load_truth(frame: Frame, size: tuple[int, int]) -> np.ndarray:
    """Decode a real photo for scoring. The ONLY place the evaluation reads a held-out image."""
    if frame.image is not None:
        img = frame.image
        return img if (img.shape[1], img.shape[0]) == tuple(size) else resize_image(img, size)
    if frame.path is None:
        raise InputError(f"frame {frame.name}: no photo to score against")
    return load_image(frame.path, size=size)


def _score(pred: np.ndarray, truth: np.ndarray, use_lpips: bool) -> dict:
    return {"psnr": metrics.psnr(pred, truth), "ssim": metrics.ssim(pred, truth),
            "lpips": metrics.lpips(pred, truth) if use_lpips else None}


def versions() -> dict:
    """Versions of everything that produced the numbers (missing packages are None)."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for name in ("sparself", "torch", "numpy", "pycolmap", "kornia", "cv2", "skimage"):
        try:
            mod = __import__(name)
            out[name] = getattr(mod, "__version__", None)
        except Exception:
            out[name] = None
    try:
        out["git_commit"] = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent, capture_output=True,
            text=True, timeout=10).stdout.strip() or None
    except Exception:
        out["git_commit"] = None
    return out


# ---- synthesizers and reconstructors ---------------------------------------------------------------

def network_factory(cfg: EvalConfig) -> Callable[[Scene, int], SynthFn]:
    """The one adapter to the CNN-LSTM: ``make(inputs, seed)`` trains ``sparself.train.train`` with
    ``cfg.train`` (seed, size and epochs from the evaluation) on the inputs, in a temporary run folder, and
    returns the bound ``synthesize(scene, targets) -> Synthesized`` (images and confidence)."""
    # resolved (and warned about) once, not once per scene and seed
    weights = cfg.train.weights if cfg.train.weights is not None else default_weights()
    base = replace(cfg.train, size=cfg.size, weights=weights,
                   epochs=cfg.epochs if cfg.epochs is not None else cfg.train.epochs)

    def make(scene: Scene, seed: int) -> SynthFn:
        with tempfile.TemporaryDirectory(prefix="sparself-eval-run-") as tmp:
            run = train(scene, Path(tmp) / "run", replace(base, seed=seed), progress=cfg.progress)
        return lambda sc, targets, **_: synthesize_with_confidence(run, sc, targets)

    return make


def _baseline_fns(names: Sequence[str]) -> dict[str, SynthFn]:
    unknown = [n for n in names if n not in BASELINES]
    if unknown:
        raise ConfigError(f"unknown baseline(s) {unknown}; known: {sorted(BASELINES)}")
    return {n: BASELINES[n] for n in names}


def reconstructor(name: str, cfg: EvalConfig) -> Callable[[Scene], object]:
    """fit(scene) -> renderer for a reconstructor name (:func:`sparself.recon.get_reconstructor`), with
    the evaluation's settings applied."""
    fit = get_reconstructor(name)
    kw = {"nerf": dict(steps=cfg.nerf_steps, seed=cfg.recon_seed, progress=cfg.progress),
          "gsplat": dict(seed=cfg.recon_seed, progress=cfg.progress),
          "3dgs": dict(seed=cfg.recon_seed, progress=cfg.progress)}.get(name, {})
    return lambda sc: fit(sc, **kw)


# ---- one scene -------------------------------------------------------------------------------------

def _with_images(scene: Scene, extra: list[Frame], images, confidence: np.ndarray | None = None) -> Scene:
    """scene plus ``extra`` frames carrying in-memory images (and their confidence maps), sorted by capture
    index."""
    images = np.asarray(images, np.float32).reshape(len(extra), *np.shape(images)[1:])
    return densify_scene(scene, list(extra), images, confidence)


def _snap(index: float, split: Split) -> int | None:
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


def _plan(inputs: Scene, split: Split, cfg: EvalConfig, full: Scene) -> tuple[list[Frame], list[dict]]:
    """Planned novel frames (pose only) and how each relates to a real photo (dense: snapped midpoints and
    extrapolations)."""
    planned = plan_poses(inputs, PlanConfig(n_mid=cfg.n_mid, n_extra=cfg.n_extra, order="capture"))
    info: list[dict] = []
    out: list[Frame] = []
    for f in planned:
        rec = {"name": f.name, "planned_index": f.index, "group": split.group(f.index), "truth": None}
        j = _snap(f.index, split)
        if j is not None:
            real = full.frames[j]
            rec.update(truth=j, truth_name=real.name,
                       snap_move=float(np.linalg.norm(real.pose.center - f.pose.center) / full.scale()),
                       snap_turn_deg=float(rotation_angle_deg(real.pose.R, f.pose.R)))
            f = _pose_only(real, name=f"novel_at_{real.name}", synthetic=True)
        out.append(f)
        info.append(rec)
    return out, info


def scene_name(scene: Scene) -> str:
    """The capture's folder name (a pose file's folder: ``middlebury_dinoSparseRing``, not ``dinoSR_par.txt``)."""
    if scene.source is None:
        return str(scene.meta.get("name", "scene"))
    return name_from_source(scene.source)


def name_from_source(source: str | Path) -> str:
    """``.../llff_bird/sparse/0`` -> ``llff_bird``; ``.../dino/dinoSR_par.txt`` -> ``dino``."""
    src = Path(source)
    if src.suffix:
        src = src.parent
    while (src.name.isdigit() or src.name == "sparse") and src.parent != src:
        src = src.parent
    return src.name


@dataclass
class _SceneEval:
    """One scene's evaluation as its named steps fill it in: the split, the inputs and planned poses, the
    images each method synthesized at the planned poses, and the results (``res``, JSON-able)."""

    name: str
    cfg: EvalConfig
    full: Scene
    split: Split
    scored: list[int]  # held-out frames that are scored
    inputs: Scene
    planned: list[Frame]
    mid_truth: dict[int, int]  # planned pose k -> the real frame at it (dense: midpoints and extrapolations)
    res: dict
    out_dir: Path | None = None
    ex_dir: Path | None = None
    net_planned: list[np.ndarray] = field(default_factory=list)  # per seed
    net_conf: list[np.ndarray | None] = field(default_factory=list)  # their confidence (T, H, W), per seed
    net_synth: SynthFn | None = None  # the first seed's network, kept to synthesize the validation views
    validation: ValidationViews | None = None  # made once per scene, shared by every reconstructor
    baseline_planned: dict[str, np.ndarray] = field(default_factory=dict)
    on_partial: Callable[[dict], None] | None = None  # called with ``res`` after each finished step

    def partial(self) -> None:
        if self.on_partial is not None:
            self.on_partial(self.res)

    @property
    def targets(self) -> list[Frame]:
        """The scored held-out frames as poses only (what synthesizers and renderers see)."""
        return [_pose_only(self.full.frames[i]) for i in self.scored]

    @property
    def mid_targets(self) -> list[int]:
        return list(self.mid_truth.values())

    def score(self, images: np.ndarray, label: str, idx: list[int], *, held_out: bool = True,
              seed: int | None = None, views: int | None = None) -> ScoredSet:
        """Score ``images`` against the real photos of frames ``idx``; for held-out frames among the
        examples, also save the images (and the ground truth once) for the report."""
        rows = []
        for k, i in enumerate(idx):
            frame = self.full.frames[i]
            truth = _load_truth(frame, self.full.image_size(i))
            rows.append(FrameScore(frame.name, i, **_score(images[k], truth, self.cfg.lpips), group=self.split.group(i)))
            if held_out and self.ex_dir is not None and i in self.scored[: self.cfg.examples]:
                self._save_example(frame.name, label, images[k], truth)
        return ScoredSet(rows, seed=seed, views=views)

    def _save_example(self, frame: str, label: str, image: np.ndarray, truth: np.ndarray) -> None:
        d = self.ex_dir / _safe(frame)
        d.mkdir(exist_ok=True)
        if not (d / "ground_truth.png").exists():
            save_image(d / "ground_truth.png", truth)
        save_image(d / f"{_safe(label)}.png", image)
        ex = self.res["examples"].setdefault(frame, {})
        ex["ground_truth"] = str((d / "ground_truth.png").relative_to(self.out_dir))
        ex[label] = str((d / f"{_safe(label)}.png").relative_to(self.out_dir))


def _sorted_resized(scene: Scene, cfg: EvalConfig) -> Scene:
    """The capture in index order at the evaluation's size, re-indexed 0..n-1."""
    order = sorted(range(len(scene)), key=lambda i: scene.frames[i].index)
    full = scene.subset(order).resized(cfg.size)
    return replace(full, frames=[replace(f, index=float(k)) for k, f in enumerate(full.frames)])


def input_points(full: Scene, cameras: dict, inputs: list[int], cfg: EvalConfig, res: dict) -> Scene:
    """``full`` with its sparse points set by ``cfg.points``, recorded in ``res["input_points"]``.

    "inputs": triangulated from the photos of frames ``inputs`` alone (at their original ``cameras``, up to
    800 px), never a held-out one; fewer than MIN_POINTS are dropped (the reconstructors then fall back as on a
    capture without points; noted). "capture": the capture's own points. Called before anything is fitted:
    ``ev.inputs`` inherits these points, and every row of the scene (N, N + sparself, weighted, densify
    baselines, oracle) fits on ``ev.inputs`` plus frames, so all rows share the same points."""
    if cfg.points == "capture":
        res["input_points"] = {"source": "capture", "points": 0 if full.points is None else len(full.points)}
        return full
    tri = triangulate(replace(full.subset(inputs), cameras=cameras))
    res["input_points"] = {"source": "inputs", "points": len(tri.points), "views": tri.views, "pairs": tri.pairs,
                           "matches": tri.matches, "seconds": tri.seconds}
    if len(tri.points) < MIN_POINTS:
        res["notes"].append(f"{len(tri.points)} points triangulated from the inputs (< {MIN_POINTS}): none used, "
                            "the reconstructors start without sparse points")
        meta = {k: v for k, v in full.meta.items() if k not in ("point_colors", "observations")}  # the capture's
        return replace(full, points=None, meta=meta)
    return with_points(full, tri)


def _protocol(ev: _SceneEval, plan_info: list[dict]) -> dict:
    """What the report says about the split, and the cameras for its plot."""
    full, split = ev.full, ev.split
    return {
        "kind": split.kind, "rule": split.rule, "n_frames": len(full),
        "held_out": [full.frames[i].name for i in split.eval], "held_out_index": split.eval,
        "scored": [full.frames[i].name for i in ev.scored],
        "inputs": [full.frames[i].name for i in split.inputs], "inputs_index": split.inputs,
        "extrapolated": [full.frames[i].name for i in ev.scored if split.group(i) == EXTRAPOLATED],
        "margin": [full.frames[i].name for i in split.margin],
        "image_size": list(full.image_size(0)), "planned": plan_info,
        "camera_frames": {
            "inputs": [f.pose.as_vector().tolist() for f in ev.inputs.frames],
            "held_out": [f.pose.as_vector().tolist() for f in ev.targets],
            "planned": [f.pose.as_vector().tolist() for f in ev.planned],
        },
    }


def _start_scene(scene: Scene, cfg: EvalConfig, out_dir: Path | None) -> _SceneEval:
    """Split the capture, plan the novel poses and draw the cameras."""
    name = scene_name(scene)
    res: dict = {"name": name, "source": str(scene.source) if scene.source else None, "status": "running",
                 "notes": [], "timings": {}}
    full = _sorted_resized(scene, cfg)
    split = make_split(len(full), cfg)
    if len(split.eval) == 0:
        raise InputError(f"{name}: {len(full)} frames leave no interior frame to hold out")
    full = input_points(full, scene.cameras, split.inputs, cfg, res)
    scored = split.eval
    if cfg.max_eval and len(scored) > cfg.max_eval:
        scored = [scored[p] for p in np.round(np.linspace(0, len(scored) - 1, cfg.max_eval)).astype(int)]
    inputs = preloaded(full.subset(split.inputs))
    planned, plan_info = _plan(inputs, split, cfg, full)
    mid_truth = {k: rec["truth"] for k, rec in enumerate(plan_info) if rec["truth"] is not None}
    ev = _SceneEval(name, cfg, full, split, scored, inputs, planned, mid_truth, res, out_dir)
    res["protocol"] = _protocol(ev, plan_info)
    if out_dir is not None and cfg.examples > 0:
        ev.ex_dir = Path(out_dir) / "examples" / _safe(name)
        ev.ex_dir.mkdir(parents=True, exist_ok=True)
        _camera_plot(inputs, planned, [_pose_only(full.frames[i]) for i in split.eval], ev.ex_dir / "cameras.png", name)
        res["camera_plot"] = str((ev.ex_dir / "cameras.png").relative_to(out_dir))
    res["examples"] = {}
    return ev


def _planned_scores(ev: _SceneEval, images: np.ndarray, label: str, seed: int | None = None) -> dict[str, ScoredSet]:
    """The planned views that have a real photo at their pose, scored: {"midpoints": ..., "extrapolations":
    ...} (a set only where it has frames)."""
    if not ev.mid_truth:
        return {}
    scored = ev.score(images[list(ev.mid_truth)], label, ev.mid_targets, held_out=False, seed=seed)
    sets = {"midpoints": scored.only(INTERPOLATED), "extrapolations": scored.only(EXTRAPOLATED)}
    return {k: v for k, v in sets.items() if v.frames}


def _network_synthesis(ev: _SceneEval, network: Callable[[Scene, int], SynthFn] | None) -> None:
    """Train the network per seed on the inputs; score it at the held-out poses and the planned poses
    with a real photo (midpoints and extrapolations)."""
    if network is None:
        try:
            network = network_factory(ev.cfg)
        except SparselfError as e:
            ev.res["notes"].append(str(e))
            return
    held, planned = SeededSets(), {k: SeededSets() for k in PLANNED_SECTIONS}
    first = ev.cfg.first_seed
    for seed in tqdm(range(first, first + ev.cfg.seeds), desc=f"{ev.name}: network seeds", disable=not ev.cfg.progress, leave=False):
        synth = network(ev.inputs, seed)
        if seed == first:
            ev.net_synth = synth
        imgs, _ = _images_and_confidence(synth(ev.inputs, ev.targets))
        held.per_seed.append(ev.score(imgs, f"{NETWORK} seed {seed}" if seed else NETWORK, ev.scored, seed=seed))
        imgs, conf = _images_and_confidence(synth(ev.inputs, ev.planned))
        ev.net_planned.append(imgs)
        ev.net_conf.append(conf)
        for sec, scored in _planned_scores(ev, imgs, NETWORK, seed).items():
            planned[sec].per_seed.append(scored)
    ev.res["view_synthesis"][NETWORK] = held.to_json()
    for sec, sets in planned.items():
        if sets.per_seed:
            ev.res[sec][NETWORK] = sets.to_json()


def _images_and_confidence(out) -> tuple[np.ndarray, np.ndarray | None]:
    """A synthesizer's answer as (images, confidence or None): the network's is a Synthesized."""
    return (out.images, out.confidence) if isinstance(out, Synthesized) else (np.asarray(out), None)


def _baseline_synthesis(ev: _SceneEval, baselines: dict[str, SynthFn]) -> None:
    """Each baseline at the held-out poses and the planned poses with a real photo (and the planned poses
    it densifies)."""
    vs = ev.res["view_synthesis"]
    for bname, fn in tqdm(list(baselines.items()), desc=f"{ev.name}: baselines", disable=not ev.cfg.progress, leave=False):
        try:
            vs[bname] = ev.score(fn(ev.inputs, ev.targets), bname, ev.scored).to_json()
            if bname in ev.cfg.densify_baselines or ev.mid_truth:
                ev.baseline_planned[bname] = fn(ev.inputs, ev.planned)
                for sec, scored in _planned_scores(ev, ev.baseline_planned[bname], bname).items():
                    ev.res[sec][bname] = scored.to_json()
        except Exception as e:  # one broken baseline must not hide the others
            log.warning("%s: baseline %s failed: %s", ev.name, bname, e)
            vs[bname] = {"error": f"{type(e).__name__}: {e}"}


def _oracle_scene(ev: _SceneEval) -> Scene:
    """The inputs plus the real photos at the snapped planned poses (planned poses without one, e.g.
    extrapolations with no extrapolation margin, keep the network's seed-0 views, where it ran)."""
    fill = ev.net_planned[0] if ev.net_planned else None
    imgs, extra = [], []
    for k, f in enumerate(ev.planned):
        if k in ev.mid_truth:
            # a real, non-held-out photo at exactly this pose (a between or margin frame, never an evaluation frame)
            imgs.append(ev.full.load(ev.mid_truth[k]))
            extra.append(f)
        elif fill is not None:
            imgs.append(fill[k])
            extra.append(f)
    return _with_images(ev.inputs, extra, imgs)


def _densified_scenes(ev: _SceneEval) -> list[tuple[str, int | None, Scene]]:
    """(key, network seed or None, scene) for every reconstruction: N alone, N + each seed's network
    views, N + each densify-baseline's views, and the oracle."""
    runs: list[tuple[str, int | None, Scene]] = [("base", None, ev.inputs)]
    for seed, imgs in enumerate(ev.net_planned, start=ev.cfg.first_seed):
        runs.append((NETWORK, seed, _with_images(ev.inputs, ev.planned, imgs)))
    for b in ev.cfg.densify_baselines:
        if b in ev.baseline_planned:
            runs.append((b, None, _with_images(ev.inputs, ev.planned, ev.baseline_planned[b])))
    if ev.cfg.oracle and ev.split.kind == "dense" and ev.mid_truth:
        runs.append(("oracle", None, _oracle_scene(ev)))
    return runs


def oracle_share(entry: dict) -> None:
    """The instrument check, then the share, of one reconstructor on one capture: more real photos must
    not make it worse.

    Sets ``instrument`` ("ok", or "failed: ..." when N + real photos (the oracle) does not beat N alone),
    ``oracle_gain_db``, and ``oracle_share`` (``oracle_share_weighted`` for "N + sparself, weighted") only
    when the instrument holds and the gain is measurable."""
    if "oracle" not in entry or "base" not in entry:
        return
    b = entry["base"]["summary"]["psnr"]["mean"]
    o = entry["oracle"]["summary"]["psnr"]["mean"]
    entry["oracle_gain_db"] = float(o - b)
    entry["instrument"] = "ok" if o > b else (
        f"failed: N + real photos {o:.2f} dB is not better than N alone {b:.2f} dB")
    for key, share in ((NETWORK, "oracle_share"), (NETWORK_WEIGHTED, "oracle_share_weighted")):
        if "summary" in entry.get(key, {}):
            entry[share] = share_of_oracle_gain(b, entry[key]["summary"]["psnr"]["mean"], o)


def _reconstruct(ev: _SceneEval, rname: str, fit: Callable[[Scene], object], entry: dict) -> None:
    """Fit ``rname`` on every densified scene and score its renders at the held-out poses, into ``entry``
    (which keeps what was done if a fit fails)."""
    net = SeededSets()
    for key, seed, sc in tqdm(_densified_scenes(ev), desc=f"{ev.name}: {rname} fits", disable=not ev.cfg.progress, leave=False):
        renderer = fit(sc)
        entry.setdefault("backend", getattr(renderer, "backend", None))
        imgs = _render_targets(ev, renderer)
        label = f"{rname} {len(sc)} views ({key if seed is None else f'{key} seed {seed}'})"
        scored = ev.score(imgs, label, ev.scored, seed=seed, views=len(sc))
        if seed is None:
            entry[key] = scored.to_json()
        else:
            net.per_seed.append(scored)
            entry.setdefault(NETWORK, {"per_seed": []})["per_seed"].append(scored.to_json())
    if net.per_seed:
        entry[NETWORK] = net.to_json()
    if ev.cfg.weighted and ev.net_planned:
        try:
            _weighted_fits(ev, rname, fit, entry)
        except Exception as e:  # the plain results stand without it
            log.warning("%s: %s weighted densification failed: %s", ev.name, rname, e)
            entry[NETWORK_WEIGHTED] = {"error": f"{type(e).__name__}: {e}"}
    oracle_share(entry)
    entry["status"] = "ok"


def _render_targets(ev: _SceneEval, renderer) -> np.ndarray:
    """The renderer's images at the scored held-out poses (poses only: no pixels reach it)."""
    return np.stack([renderer.render(t.pose, ev.full.cameras[t.camera_id]) for t in ev.targets])


def weighted_scene(scene: Scene, planned: list[Frame], images: np.ndarray, confidence: np.ndarray | None,
                   weight: float) -> Scene:
    """``scene`` + synthesized frames carrying their confidence maps (None: weight only) and loss ``weight``."""
    sc = _with_images(scene, planned, images, confidence)
    return replace(sc, frames=[replace(f, weight=float(weight)) if f.synthetic else f for f in sc.frames])


def validation_inputs(n: int) -> list[int]:
    """Positions among n input views held back to choose the synthetic-frame weight: every
    VALIDATION_EVERY-th interior one from the third (the middle one when that gives none).

    >>> validation_inputs(25)
    [2, 7, 12, 17, 22]
    """
    return list(range(2, n - 1, VALIDATION_EVERY)) or ([n // 2] if n >= 3 else [])


def validation_split(inputs: Scene) -> tuple[list[int], Scene]:
    """(the :func:`validation_inputs` positions, the inputs without them) for choosing the weight."""
    val = validation_inputs(len(inputs))
    if not val:
        raise ConfigError(f"{len(inputs)} input views leave none to choose the synthetic-frame weight on")
    return val, inputs.without(val)


@dataclass
class ValidationViews:
    """The planned views that the weight-choosing fits train on, and the names of the source views they
    were synthesized from."""

    images: np.ndarray  # (T, H, W, 3)
    confidence: np.ndarray | None  # (T, H, W)
    sources: list[str]


def validation_views(inputs: Scene, planned: list[Frame], synth: SynthFn) -> ValidationViews:
    """The planned views synthesized by ``synth`` from the inputs minus the held-back ones, so no pixel of a
    held-back view reaches the validation fits through them (the network's weights, trained on all inputs,
    did see them: this removes the leak through the images, not through training)."""
    _, train = validation_split(inputs)
    images, confidence = _images_and_confidence(synth(train, planned))
    return ValidationViews(images, confidence, [f.name for f in train.frames])


def choose_weight(inputs: Scene, planned: list[Frame], views: ValidationViews, grid: Sequence[float],
                  fit: Callable[[Scene], object]) -> dict:
    """The synthetic-frame weight of ``grid`` whose fit on the inputs minus :func:`validation_inputs` (+ the
    planned ``views``) renders those held-back *input* views best (mean PSNR; the first on ties). Reads the
    inputs' pixels only, never a held-out photo; ``views`` must be synthesized without the held-back inputs
    (:func:`validation_views`), or their pixels would favour larger weights."""
    val, train = validation_split(inputs)
    leaked = sorted(set(views.sources) & {inputs.frames[i].name for i in val})
    if leaked:
        raise ValueError(f"validation views synthesized from held-back input(s) {leaked}")
    scores = {}
    for w in grid:
        r = fit(weighted_scene(train, planned, views.images, views.confidence, w))
        scores[float(w)] = float(np.mean([metrics.psnr(r.render(inputs.frames[i].pose, inputs.camera(i)),
                                                       inputs.load(i)) for i in val]))
    best = max(scores, key=lambda w: scores[w])
    return {"weight": best, "validation_psnr": {str(w): v for w, v in scores.items()},
            "validation_views": [inputs.frames[i].name for i in val], "validation_sources": list(views.sources),
            "confidence": views.confidence is not None}


def _weighted_fits(ev: _SceneEval, rname: str, fit: Callable[[Scene], object], entry: dict) -> None:
    """'N + sparself, weighted': per seed, the inputs + its views (synthesized from all inputs) with their
    confidence as per-pixel loss weights and the synthetic-frame weight :func:`choose_weight` picked on the
    run's first seed (its network's views synthesized again without the held-back inputs)."""
    if ev.validation is None:
        ev.validation = validation_views(ev.inputs, ev.planned, ev.net_synth)
    choice = choose_weight(ev.inputs, ev.planned, ev.validation, ev.cfg.synthetic_weights, fit)
    choice["chosen_on_seed"] = ev.cfg.first_seed
    sets, records = SeededSets(), []
    for k, seed in enumerate(range(ev.cfg.first_seed, ev.cfg.first_seed + len(ev.net_planned))):
        sc = weighted_scene(ev.inputs, ev.planned, ev.net_planned[k], ev.net_conf[k], choice["weight"])
        label = f"{rname} {len(sc)} views ({NETWORK_WEIGHTED} seed {seed})"
        sets.per_seed.append(ev.score(_render_targets(ev, fit(sc)), label, ev.scored, seed=seed, views=len(sc)))
        records.append({**sets.per_seed[-1].to_json(), "selection": choice})
    entry[NETWORK_WEIGHTED] = {**sets.to_json(), "per_seed": records}


def _densification(ev: _SceneEval, reconstructors: dict[str, Callable[[Scene], object]] | None) -> None:
    """Each reconstructor from N views vs N + synthesized views vs the oracle; a failure is recorded."""
    recs = reconstructors if reconstructors is not None else {}
    dens: dict = {}
    ev.res["densification"] = dens
    for rname in ev.cfg.reconstructors if reconstructors is None else list(recs):
        t0 = time.perf_counter()
        entry = dens[rname] = {}
        try:
            _reconstruct(ev, rname, recs[rname] if rname in recs else reconstructor(rname, ev.cfg), entry)
        except Exception as e:
            log.warning("%s: reconstructor %s failed: %s", ev.name, rname, e)
            entry.update(status="failed", error=f"{type(e).__name__}: {e}")
        entry["seconds"] = time.perf_counter() - t0
        ev.partial()


def evaluate_scene(scene: Scene, cfg: EvalConfig, out_dir: Path | None = None, *,
                   network: Callable[[Scene, int], SynthFn] | None = None,
                   reconstructors: dict[str, Callable[[Scene], object]] | None = None,
                   baselines: dict[str, SynthFn] | None = None,
                   on_partial: Callable[[dict], None] | None = None) -> dict:
    """Run the protocol on one scene. Returns the scene's results (JSON-able).

    network: ``make(inputs_scene, seed) -> synthesize`` (default: :func:`network_factory`); None when
    unavailable is recorded. ``synthesize(sources, targets)`` gets the inputs as sources, and for the
    weighted row's weight choice (first seed) the inputs minus :func:`validation_inputs`.
    reconstructors / baselines: override the registries (tests).
    out_dir: where example images are saved (``examples/<scene>/``); None saves none.
    on_partial: called with the results so far after the network, the baselines and each reconstructor
    (long runs can save what they have).
    """
    t_start = time.perf_counter()
    ev = _start_scene(scene, cfg, out_dir)
    ev.on_partial = on_partial
    ev.res["view_synthesis"] = {}
    ev.res.update({sec: {} for sec in PLANNED_SECTIONS})
    t0 = time.perf_counter()
    _network_synthesis(ev, network)
    ev.res["timings"]["network"] = time.perf_counter() - t0
    ev.partial()
    t0 = time.perf_counter()
    _baseline_synthesis(ev, baselines if baselines is not None else _baseline_fns(cfg.baselines))
    ev.res["timings"]["baselines"] = time.perf_counter() - t0
    ev.partial()
    _densification(ev, reconstructors)
    ev.res["status"] = "ok"
    ev.res["timings"]["total"] = time.perf_counter() - t_start
    return ev.res


def _camera_plot(inputs: Scene, planned: list[Frame], held: list[Frame], path: Path, name: str) -> None:
    try:
        plot_cameras(inputs, planned, held, path=path, title=f"{name}: inputs, planned (synthesized), held-out")
    except Exception as e:  # a missing plot is not worth failing the evaluation
        log.warning("camera plot failed: %s", e)


# ---- many scenes -----------------------------------------------------------------------------------

def read_manifest(path: Path) -> list[Path]:
    """Scene paths listed one per line (blank lines and # comments ignored; relative to the file)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: manifest not found")
    out = []
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            p = Path(line)
            out.append(p if p.is_absolute() else path.parent / p)
    if not out:
        raise InputError(f"{path}: manifest lists no scenes")
    return out


def run_evaluation(scenes: Sequence[Scene | Path], cfg: EvalConfig, out_dir: Path | None = None, **hooks) -> dict:
    """Evaluate every scene (paths are read with sparself.io.read_scene); failures are recorded.

    Returns {"settings", "scenes": [...], "not_run": {...}}. hooks are passed to :func:`evaluate_scene`.
    """
    cfg.validate()
    try:
        from .recon.gsplat import available as gs_available

        gs_ok, gs_why = gs_available()
    except Exception as e:
        gs_ok, gs_why = False, str(e)
    results: dict = {
        "settings": {**dataclasses.asdict(cfg), "versions": versions(),
                     "lpips_status": metrics.lpips_status() if cfg.lpips else "unavailable: disabled by settings"},
        "not_run": {"dietnerf": DIETNERF_NOTE},
        "scenes": [],
    }
    if not gs_ok:
        results["not_run"]["gsplat"] = f"not run: {gs_why}"
    if hooks.get("reconstructors") is not None:
        results["settings"]["reconstructors"] = list(hooks["reconstructors"])
    if not gs_ok and "gsplat" in cfg.reconstructors:
        cfg = replace(cfg, reconstructors=tuple(r for r in cfg.reconstructors if r != "gsplat"))
    for item in tqdm(list(scenes), desc="scenes", disable=not cfg.progress):
        label = str(item) if not isinstance(item, Scene) else str(item.source or item.meta.get("name", "scene"))
        try:
            if isinstance(item, Scene):
                scene = item
            else:
                scene = read_scene(Path(item))
            results["scenes"].append(evaluate_scene(scene, cfg, out_dir, **hooks))
        except Exception as e:
            log.error("%s: evaluation failed: %s", label, e)
            results["scenes"].append({"name": Path(label).name, "source": label, "status": "failed",
                                      "error": f"{type(e).__name__}: {e}",
                                      "traceback": traceback.format_exc(limit=5)})
    return results


def evaluate(scenes: Sequence[Scene | Path], out: Path, cfg: EvalConfig | None = None, *,
             overwrite: bool = False, **hooks) -> dict:
    """Run the protocol and write ``results.json``, ``report.md``, ``report.html`` and figures to ``out``
    (atomically: nothing is left there if it fails). Returns the results."""
    cfg = cfg or EvalConfig()
    cfg.validate()
    with atomic_dir(Path(out), overwrite, evaluation_inputs(scenes)) as tmp:
        results = run_evaluation(scenes, cfg, tmp, **hooks)
        (tmp / "results.json").write_text(json.dumps(_jsonable(results), indent=1, allow_nan=True))
        write_report(results, tmp)
    return results


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    return x


def run_cli(scene_paths: Sequence[Path], out: Path, manifest: Path | None = None, *, quick: bool = False,
            overwrite: bool = False, train_cfg: TrainConfig | None = None, **given) -> dict:
    """What ``sparself evaluate`` does: gather scenes (arguments + manifest) and call :func:`evaluate`.

    given: :class:`EvalConfig` fields set on the command line; the others keep the defaults of
    :class:`EvalConfig` (or of :meth:`EvalConfig.quick`). train_cfg: the network's training options.
    """
    check_not_input(out, [Input("manifest", manifest)])
    paths = [Path(p) for p in scene_paths] + (read_manifest(manifest) if manifest else [])
    if not paths:
        raise InputError("no scenes given (pass scene folders or --manifest FILE)")
    from .progress import show_progress

    cfg = eval_config(quick=quick, train_cfg=train_cfg, **given)
    cfg = replace(cfg, progress=cfg.progress and show_progress())  # no bar fragments in a log file, none with -q
    return evaluate(paths, out, cfg, overwrite=overwrite)


def eval_config(*, quick: bool = False, train_cfg: TrainConfig | None = None, **given) -> EvalConfig:
    """The command line's EvalConfig: the fields given (None: not given) over the defaults of
    :class:`EvalConfig` or of :meth:`EvalConfig.quick`; train_cfg: the network's training options."""
    cfg = EvalConfig.quick() if quick else EvalConfig()
    return replace(cfg, **{k: v for k, v in given.items() if v is not None}, train=train_cfg or cfg.train)
