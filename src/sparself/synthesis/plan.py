"""The paper's novel-pose plan (section 3.2): midpoints between consecutive views and extrapolations
beyond the ends of the capture path.

A planned pose is the LERP of two camera centres and the shortest-arc SLERP of their rotations
(:func:`sparself.core.geometry.interpolate_pose`), at t = 0.5 between two consecutive views and at t = 1.2
past the last (and, mirrored, the first) view. By default 8 midpoints + 2 extrapolations = 10 new poses,
the paper's 25 + 10 setting.

Design decisions (documented here because they change which poses come out):

* **Which views are consecutive.** ``order="capture"`` takes the scene's frame order. ``"nearest"``
  builds a greedy nearest-neighbour path (distance = camera-centre distance in units of the scene
  scale + rotation angle in radians, so a rotation-only capture still orders). ``"auto"`` keeps the
  capture order unless its path is more than ``AUTO_RATIO`` (1.5x) longer than the nearest-neighbour
  path: a real sequential capture walks about as far as the greedy path (often less), a shuffled or
  name-sorted unordered set walks many times further.
* **Which gaps get a midpoint.** There are N - 1 gaps for ``n_mid`` midpoints. ``gaps="even"`` (default)
  spreads them evenly along the path, as the paper's evenly captured 25 views imply, so the new views
  cover the whole trajectory. ``gaps="largest"`` takes the widest gaps (centre distance + rotation, as
  above) instead, which suits uneven captures. When ``n_mid > N - 1`` it is capped at N - 1 (logged).
* **Extrapolations.** They alternate between the end (pair (N-2, N-1), t = 1.2) and the start
  (pair (1, 0), t = 1.2); a second one at the same end continues further (t = 1.4, 1.6, ...).
* **Fractional index.** A planned frame's ``index`` is the LERP of its pair's indices at the same t
  (3.5 between frames 3 and 4; N - 1 + 0.2 past the end; -0.2 before the start). When the frames'
  own indices are not monotonic along the path (a nearest-neighbour path through an unordered set),
  positions along the path are used instead. :func:`plan_sequence` returns the targets together with
  the scene re-indexed along the path, so sources and targets share one index scale — use it where the
  order may be a nearest-neighbour path (training and synthesis read the indices).

Cost: the nearest-neighbour path is O(N^2) time and O(N) memory (one distance row at a time), so
500 views plan in well under a second.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from sparself.capture.scene import Frame, Scene
from sparself.core.errors import ConfigError, InputError
from sparself.core.geometry import interpolate_pose
from sparself.core.options import check_choices, option
from sparself.core.outputs import atomic_file
from sparself.synthesis.ordering import indices_along, plan_order, reindexed, step_costs
from sparself.synthesis.plan_files import PLAN_FORMAT, PLAN_VERSION, novel_name, source_record

log = logging.getLogger(__name__)


@dataclass
class PlanConfig:
    """How many novel poses to plan and where (each field's help is its documentation; the order rules
    are in the module docstring)."""

    n_mid: int = option(8, "midpoints between consecutive views (the paper: 8)")
    n_extra: int = option(2, "extrapolated poses past the ends of the path (the paper: 2)")
    t_mid: float = option(0.5, "interpolation parameter of a midpoint")
    t_extra: float = option(1.2, "extrapolation parameter past the pair's second view")
    order: Literal["auto", "capture", "nearest"] = option(
        "auto",
        "which views are consecutive: capture order, a nearest-neighbour path, or "
        "auto (capture order unless it walks 1.5x further than the nearest-neighbour path)",
    )
    gaps: Literal["even", "largest"] = option("even", "which gaps get midpoints: spread evenly or the widest ones")

    def validate(self) -> None:
        if int(self.n_mid) != self.n_mid or self.n_mid < 0:
            raise ConfigError(f"n_mid must be a non-negative integer, got {self.n_mid}")
        if int(self.n_extra) != self.n_extra or self.n_extra < 0:
            raise ConfigError(f"n_extra must be a non-negative integer, got {self.n_extra}")
        if not (0.0 < self.t_mid < 1.0):
            raise ConfigError(f"t_mid must lie strictly between 0 and 1, got {self.t_mid}")
        if not (self.t_extra > 1.0 and math.isfinite(self.t_extra)):
            raise ConfigError(f"t_extra must be a finite number > 1, got {self.t_extra}")
        check_choices(self)
        if self.n_mid == 0 and self.n_extra == 0:
            raise ConfigError("--n-mid 0 and --n-extra 0 plan no novel pose at all; give one of them above 0")


# ---- ordering ------------------------------------------------------------------------------------


# ---- the plan ------------------------------------------------------------------------------------


def _choose_gaps(scene: Scene, seq: np.ndarray, n_mid: int, how: str) -> np.ndarray:
    n_gaps = len(seq) - 1
    if n_mid > n_gaps:
        log.warning(
            "asked for %d midpoints but %d views have only %d gaps: planning %d", n_mid, len(seq), n_gaps, n_gaps
        )
        n_mid = n_gaps
    if n_mid == 0:
        return np.zeros(0, dtype=np.int64)
    if how == "largest":
        centers, quats, scale = scene.centers(), np.stack([p.qvec for p in scene.poses]), scene.scale()
        widths = np.array([step_costs(centers, quats, scale, seq[g], np.array([seq[g + 1]]))[0] for g in range(n_gaps)])
        # stable sort: among equal gaps the earlier wins, so the result is deterministic
        return np.sort(np.argsort(-widths, kind="stable")[:n_mid])
    # Evenly spread: the centre of each of n_mid equal stretches of the path, symmetric about its middle.
    return np.floor((np.arange(n_mid) + 0.5) * n_gaps / n_mid).astype(np.int64)


def planned_frame(scene: Scene, ia: int, ib: int, index_a: float, index_b: float, t: float) -> Frame:
    """The novel frame at ``t`` along the pose path from frame ``ia`` (index ``index_a``) to ``ib`` (t > 1:
    past ``ib``)."""
    fa, fb = scene.frames[ia], scene.frames[ib]
    pose = interpolate_pose(fa.pose, fb.pose, t)
    index = round(float(index_a + t * (index_b - index_a)), 9)  # -0.2, not -0.19999999999999996
    cam = fa.camera_id if t <= 0.5 else fb.camera_id  # the camera of the nearer view
    return Frame(name=novel_name(index), pose=pose, camera_id=cam, index=index, path=None, synthetic=True)


def extra_t(cfg: PlanConfig, visit: int) -> float:
    """t of the ``visit``-th extrapolation (from 0) past one end: ``cfg.t_extra``, then further by the same step.

    >>> extra_t(PlanConfig(), 0), round(extra_t(PlanConfig(), 1), 6)
    (1.2, 1.4)
    """
    return 1.0 + (visit + 1) * (cfg.t_extra - 1.0)


def plan_poses(scene: Scene, cfg: PlanConfig | None = None) -> list[Frame]:
    """Novel poses for ``scene``: midpoints between consecutive views and extrapolations past the ends.

    Returns Frames sorted by index, each with pose, camera_id, fractional index, a ``novel_*.png`` name,
    ``path=None`` and ``synthetic=True`` (targets for a synthesizer). Raises InputError for fewer than
    3 views, ConfigError for a bad config.
    """
    cfg = cfg or PlanConfig()
    cfg.validate()
    n = len(scene)
    if n < 3:
        src = scene.source or "scene"
        raise InputError(f"{src}: needs at least 3 posed views to plan novel poses, got {n}")
    seq = plan_order(scene, cfg.order)
    idx = indices_along(scene, seq)
    out: list[Frame] = []
    for g in _choose_gaps(scene, seq, int(cfg.n_mid), cfg.gaps):
        out.append(planned_frame(scene, seq[g], seq[g + 1], idx[g], idx[g + 1], cfg.t_mid))
        a, b = scene.frames[seq[g]], scene.frames[seq[g + 1]]
        if np.allclose(a.pose.w2c(), b.pose.w2c(), atol=1e-9):
            log.warning(
                "%s and %s have the same pose: the midpoint between them repeats it (--gaps largest skips such gaps)",
                a.name,
                b.name,
            )
    for k in range(int(cfg.n_extra)):
        t = extra_t(cfg, k // 2)
        if k % 2 == 0:  # past the end: pair (N-2, N-1)
            out.append(planned_frame(scene, seq[-2], seq[-1], idx[-2], idx[-1], t))
        else:  # before the start: pair (1, 0)
            out.append(planned_frame(scene, seq[1], seq[0], idx[1], idx[0], t))
    out.sort(key=lambda f: f.index)
    return out


# candidate poses for a plan that looks at the reconstruction first (``densify --plan weak``): the paper's
# t values and a few more, so each gap and end is judged on more than one pose
CANDIDATE_T_MID = (0.25, 0.5, 0.75)
CANDIDATE_T_EXTRA = (1.2, 1.4)


@dataclass(frozen=True)
class Candidate:
    """A candidate novel pose, its slot: the gap of the path it lies in (0 .. N-2), or, for an
    extrapolation (``beyond``), -1 before the first view and N-1 past the last; and its t along the pair."""

    frame: Frame
    slot: int
    beyond: bool = False
    t: float = 0.5


def candidate_poses(scene: Scene, cfg: PlanConfig | None = None) -> list[Candidate]:
    """Every pose :func:`pick_poses` may choose from: in each gap of the path at the t values of
    ``CANDIDATE_T_MID`` and ``cfg.t_mid``; past both ends at ``CANDIDATE_T_EXTRA`` and ``cfg.t_extra`` (only
    when ``cfg.n_extra`` asks for extrapolations). Same poses, names and indices as :func:`plan_poses` makes."""
    cfg = cfg or PlanConfig()
    cfg.validate()
    if len(scene) < 3:
        raise InputError(
            f"{scene.source or 'scene'}: needs at least 3 posed views to plan novel poses, got {len(scene)}"
        )
    seq = plan_order(scene, cfg.order)
    idx = indices_along(scene, seq)
    out = [
        Candidate(planned_frame(scene, seq[g], seq[g + 1], idx[g], idx[g + 1], t), int(g), t=t)
        for g in range(len(seq) - 1)
        for t in sorted({*CANDIDATE_T_MID, cfg.t_mid})
    ]
    if cfg.n_extra:
        for t in sorted({*CANDIDATE_T_EXTRA, cfg.t_extra}):
            last = planned_frame(scene, seq[-2], seq[-1], idx[-2], idx[-1], t)
            out.append(Candidate(last, len(seq) - 1, True, t))
            out.append(Candidate(planned_frame(scene, seq[1], seq[0], idx[1], idx[0], t), -1, True, t))
    return out


def pick_poses(candidates: list[Candidate], weakness: np.ndarray, cfg: PlanConfig) -> list[Frame]:
    """The ``cfg.n_mid`` gaps where ``weakness`` (one number per candidate, larger = the reconstruction is
    weaker there), averaged over the gap's candidates, is largest, each with its candidate nearest
    ``cfg.t_mid``; and ``cfg.n_extra`` extrapolations alternating between the ends, the weaker end first, at
    the t values :func:`plan_poses` uses (nearest candidate). Sorted by index.

    Weakness ranks gaps, not poses inside a gap: the halves that measure it each lack one of a gap's two
    inputs, so inside a gap it mostly says how unevenly far a pose is from the halves' inputs, while a fit on
    both inputs is farthest from either at the midpoint."""
    weak = np.asarray(weakness, np.float64)
    slots: dict[tuple[bool, int], list[int]] = {}
    for k, c in enumerate(candidates):
        slots.setdefault((c.beyond, c.slot), []).append(k)
    ranked = sorted(slots, key=lambda s: -float(weak[slots[s]].mean()))  # stable: ties keep candidate order
    gaps = [s for s in ranked if not s[0]][: int(cfg.n_mid)]
    picked = [_nearest_t(candidates, slots[s], cfg.t_mid) for s in gaps]
    ends = [s for s in ranked if s[0]]
    for k in range(int(cfg.n_extra) if ends else 0):
        left = [i for i in slots[ends[k % len(ends)]] if i not in picked]
        if left:
            picked.append(_nearest_t(candidates, left, extra_t(cfg, k // len(ends))))
    return sorted((candidates[i].frame for i in picked), key=lambda f: f.index)


def weakness_decides(candidates: list[Candidate], cfg: PlanConfig) -> bool:
    """Whether :func:`pick_poses` can pick differently for another weakness: not when ``cfg.n_mid`` covers
    every gap among ``candidates`` and ``cfg.n_extra`` visits each end they reach equally often."""
    gaps = {c.slot for c in candidates if not c.beyond}
    ends = {c.slot for c in candidates if c.beyond}
    return len(gaps) > int(cfg.n_mid) or (bool(ends) and int(cfg.n_extra) % len(ends) != 0)


def _nearest_t(candidates: list[Candidate], among: list[int], t: float) -> int:
    return min(among, key=lambda i: abs(candidates[i].t - t))


def plan_sequence(scene: Scene, cfg: PlanConfig | None = None) -> tuple[Scene, list[Frame]]:
    """The plan together with the source scene on the same index scale: ``(sources, targets)``.

    ``sources`` is the scene with its frames in path order and their indices as the plan counts them
    (the scene unchanged for a capture-order plan of a normally indexed scene); use it, not ``scene``,
    for training and synthesis when the order may be a nearest-neighbour path, so that a target's
    fractional index sits between the indices of the views it was planned between.
    """
    cfg = cfg or PlanConfig()
    targets = plan_poses(scene, cfg)
    return reindexed(scene, plan_order(scene, cfg.order)), targets


# ---- plan files ----------------------------------------------------------------------------------


# ---- the `sparself plan` command ------------------------------------------------------------------


def _replaceable(path: Path, plan: bool) -> bool:
    """What --overwrite may replace: a plan file (its JSON says so) or, for the plot, a PNG image."""
    try:
        if plan:
            return json.loads(path.read_text()).get("format") == PLAN_FORMAT
        with open(path, "rb") as f:
            return f.read(8) == b"\x89PNG\r\n\x1a\n"
    except (OSError, ValueError, AttributeError):
        return False


def make_plan(
    scene_path: Path, out: Path, cfg: PlanConfig | None = None, plot: Path | None = None, overwrite: bool = False
) -> list[Frame]:
    """Read a scene, plan its novel poses, write the plan JSON (and optionally a camera plot).

    Both files are written atomically and only after everything succeeded; an existing output file is
    refused unless ``overwrite``. Returns the planned frames.
    """
    from sparself.capture.io import read_scene
    from sparself.core.errors import OutputError
    from sparself.core.outputs import Input, check_not_input, real, scene_inputs

    out = Path(out)
    if plot is not None and Path(plot).suffix.lower() != ".png":
        raise OutputError(f"{plot}: the camera plot is written as PNG; give a .png file name")
    if plot is not None and real(plot) == real(out):
        raise OutputError(f"--plot {plot} and --out {out} are the same file; give each its own name")
    outs = [out] + ([Path(plot)] if plot is not None else [])
    for p in outs:
        check_not_input(p, [Input("scene", scene_path)])
        if p.exists() and not overwrite:
            raise OutputError(f"{p}: already exists (use --overwrite to replace it)")
        if p.exists() and p.is_dir():
            raise OutputError(f"{p}: is a folder, expected a file path")
        if p.exists() and not _replaceable(p, plan=p == out):
            what = "a plan sparself wrote" if p == out else "a PNG image"
            raise OutputError(f"{p}: not {what}, so --overwrite does not replace it; choose another name")
    cfg = cfg or PlanConfig()
    cfg.validate()
    scene = read_scene(Path(scene_path))
    for p in outs:
        check_not_input(p, scene_inputs(scene))
    frames = plan_poses(scene, cfg)
    try:
        if plot is None:
            save_plan(out, frames, scene=scene, cfg=cfg)
        else:
            from sparself.capture.plot import plot_cameras

            with atomic_file(Path(plot)) as tmp_png:
                plot_cameras(scene, frames, path=tmp_png)
                save_plan(out, frames, scene=scene, cfg=cfg)  # the plot is renamed into place after this
    except OSError as e:
        raise OutputError(f"{e.filename or out}: cannot write ({e.strerror or e})") from None
    log.debug("planned %d novel poses for %d views -> %s", len(frames), len(scene), out)
    return frames


def save_plan(path: Path, frames: list[Frame], *, scene: Scene | None = None, cfg: PlanConfig | None = None) -> Path:
    """Write planned frames as JSON, atomically. qvec/tvec (COLMAP world-to-camera) are what
    :func:`load_plan` reads; c2w and centre are there for people and other tools to read."""
    path = Path(path)
    doc = {
        "format": PLAN_FORMAT,
        "version": PLAN_VERSION,
        "convention": "qvec [qw,qx,qy,qz] and tvec are COLMAP world-to-camera; c2w uses OpenCV camera axes",
        "source": str(Path(scene.source).resolve()) if scene is not None and scene.source is not None else None,
        **(source_record(scene) if scene is not None else {}),
        "config": asdict(cfg) if cfg is not None else None,
        "n_source_views": len(scene) if scene is not None else None,
        "cameras": (
            {
                str(cid): {"model": c.model, "width": c.width, "height": c.height, "params": list(c.params)}
                for cid, c in scene.cameras.items()
            }
            if scene is not None
            else None
        ),
        "frames": [
            {
                "name": f.name,
                "index": float(f.index),
                "camera_id": int(f.camera_id),
                "qvec": [float(v) for v in f.pose.qvec],
                "tvec": [float(v) for v in f.pose.tvec],
                "center": [float(v) for v in f.pose.center],
                "c2w": [[float(v) for v in row] for row in f.pose.c2w()[:3]],
            }
            for f in frames
        ],
    }
    text = json.dumps(doc, indent=1, allow_nan=False)
    with atomic_file(path) as tmp:
        tmp.write_text(text + "\n")
    return path
