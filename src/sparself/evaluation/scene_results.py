"""Typed records of one evaluated run (a capture at one N): :class:`SceneResult` (what ran: the split, the
view synthesis scores per method, the densification per reconstructor) and :class:`SceneFailure` (a run
that failed, with its error). ``results.json`` holds their :meth:`to_json` form; :meth:`from_json` reads
it back, older files included (keys they lack get their defaults; a scene's keys this version does not
know, such as a benchmark's ``wall_s``, are kept in ``extra`` and written back as read)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Literal

from sparself.evaluation.config import PlannedSection
from sparself.evaluation.results import ReconResult, Row, row_from_json


@dataclass
class PlannedPose:
    """A planned novel pose and, on a dense capture, the real frame it was snapped to (``truth``, its
    position in capture order) with how far the snap moved and turned it (move in scene scale)."""

    name: str
    planned_index: float
    group: str | None
    truth: int | None = None
    truth_name: str | None = None
    snap_move: float | None = None
    snap_turn_deg: float | None = None

    def to_json(self) -> dict:
        d: dict = {"name": self.name, "planned_index": self.planned_index, "group": self.group, "truth": self.truth}
        if self.truth is not None:
            d.update(truth_name=self.truth_name, snap_move=self.snap_move, snap_turn_deg=self.snap_turn_deg)
        return d

    @classmethod
    def from_json(cls, d: dict) -> PlannedPose:
        truth = [d.get(k) for k in ("truth", "truth_name", "snap_move", "snap_turn_deg")]
        return cls(d["name"], d["planned_index"], d.get("group"), *truth)


@dataclass
class CameraFrames:
    """The cameras of the report's plot: each pose as its 7-vector (quaternion, translation)."""

    inputs: list[list[float]] = field(default_factory=list)
    held_out: list[list[float]] = field(default_factory=list)
    planned: list[list[float]] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"inputs": self.inputs, "held_out": self.held_out, "planned": self.planned}

    @classmethod
    def from_json(cls, d: dict) -> CameraFrames:
        return cls(d.get("inputs", []), d.get("held_out", []), d.get("planned", []))


@dataclass
class SplitInfo:
    """What the report says about a run's split (``protocol`` in results.json): the kind and rule, frame
    names (and positions) held out, scored, input, extrapolated and in the margins, the image size (w, h),
    the planned poses and the cameras."""

    kind: str = ""
    rule: str = ""
    n_frames: int = 0
    held_out: list[str] = field(default_factory=list)
    held_out_index: list[int] = field(default_factory=list)
    scored: list[str] = field(default_factory=list)
    inputs: list[str] = field(default_factory=list)
    inputs_index: list[int] = field(default_factory=list)
    extrapolated: list[str] = field(default_factory=list)
    margin: list[str] = field(default_factory=list)
    image_size: list[int] = field(default_factory=list)
    planned: list[PlannedPose] = field(default_factory=list)
    camera_frames: CameraFrames = field(default_factory=CameraFrames)

    def to_json(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d.update(planned=[p.to_json() for p in self.planned], camera_frames=self.camera_frames.to_json())
        return d

    @classmethod
    def from_json(cls, d: dict) -> SplitInfo:
        plain = {f.name: d[f.name] for f in fields(cls) if f.name in d and f.name not in ("planned", "camera_frames")}
        planned = [PlannedPose.from_json(p) for p in d.get("planned", [])]
        return cls(**plain, planned=planned, camera_frames=CameraFrames.from_json(d.get("camera_frames", {})))


@dataclass
class InputPoints:
    """Where the reconstructors' sparse points came from: "capture" (its own) or "inputs" (triangulated
    from the N inputs' photos, with the views, pairs and matches used and the seconds it took)."""

    source: Literal["capture", "inputs"]
    points: int
    views: int | None = None
    pairs: int | None = None
    matches: int | None = None
    seconds: float | None = None

    def to_json(self) -> dict:
        d: dict = {"source": self.source, "points": self.points}
        if self.source == "inputs":
            d.update(views=self.views, pairs=self.pairs, matches=self.matches, seconds=self.seconds)
        return d

    @classmethod
    def from_json(cls, d: dict) -> InputPoints:
        return cls(d["source"], d["points"], d.get("views"), d.get("pairs"), d.get("matches"), d.get("seconds"))


@dataclass
class Timings:
    """Wall-clock seconds of the network, the baselines and the whole run (None: not reached)."""

    network: float | None = None
    baselines: float | None = None
    total: float | None = None

    def to_json(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    @classmethod
    def from_json(cls, d: dict) -> Timings:
        return cls(d.get("network"), d.get("baselines"), d.get("total"))

    def plus(self, other: Timings) -> Timings:
        """Both runs' seconds added (a step that one of them did not reach counts 0 there)."""
        add = [(getattr(self, f.name), getattr(other, f.name)) for f in fields(self)]
        return Timings(*(None if a is None and b is None else (a or 0.0) + (b or 0.0) for a, b in add))


def rows_from_json(d: dict) -> dict[str, Row]:
    return {name: row_from_json(v) for name, v in d.items()}


@dataclass
class ViewSynthesisResult:
    """Each method's scores (by method name) at the held-out poses, and at the planned poses that have a
    real photo: midpoints and extrapolations (dense captures)."""

    held_out: dict[str, Row] = field(default_factory=dict)
    midpoints: dict[str, Row] = field(default_factory=dict)
    extrapolations: dict[str, Row] = field(default_factory=dict)

    def planned(self, section: PlannedSection) -> dict[str, Row]:
        return self.midpoints if section == "midpoints" else self.extrapolations

    def to_json(self) -> dict:
        """The scene's three sections, as results.json has them at the scene's top level."""
        return {
            "view_synthesis": {k: v.to_json() for k, v in self.held_out.items()},
            "midpoints": {k: v.to_json() for k, v in self.midpoints.items()},
            "extrapolations": {k: v.to_json() for k, v in self.extrapolations.items()},
        }

    @classmethod
    def from_json(cls, scene: dict) -> ViewSynthesisResult:
        return cls(*(rows_from_json(scene.get(k, {})) for k in ("view_synthesis", "midpoints", "extrapolations")))


# the keys a SceneResult writes, in order; any other key of a scene read back is kept in ``extra``
SCENE_KEYS = (
    "name",
    "capture",
    "inputs_n",
    "source",
    "status",
    "notes",
    "timings",
    "input_points",
    "protocol",
    "camera_plot",
    "examples",
    "view_synthesis",
    "midpoints",
    "extrapolations",
    "densification",
)


@dataclass
class SceneResult:
    """One capture evaluated at one N: ``capture`` (None in results from before the sweep: its name is
    the capture's), N (``inputs_n``, None likewise), the scene's source, notes, timings, sparse points,
    split, camera plot and example images (frame -> label -> path relative to the output folder), the
    view synthesis scores and the densification per reconstructor name."""

    name: str
    capture: str | None = None
    inputs_n: int | None = None
    source: str | None = None
    status: Literal["running", "ok"] = "running"
    notes: list[str] = field(default_factory=list)
    timings: Timings = field(default_factory=Timings)
    input_points: InputPoints | None = None
    split: SplitInfo = field(default_factory=SplitInfo)
    camera_plot: str | None = None
    examples: dict[str, dict[str, str]] = field(default_factory=dict)
    synthesis: ViewSynthesisResult = field(default_factory=ViewSynthesisResult)
    densification: dict[str, ReconResult] = field(default_factory=dict)
    extra: dict[str, object] = field(default_factory=dict)  # keys this version does not know, as read

    @property
    def capture_name(self) -> str:
        return self.capture or self.name

    def row(self, recon: str, row: str) -> Row | None:
        """Reconstructor ``recon``'s row ``row`` (None: the reconstructor or the row did not run)."""
        d = self.densification.get(recon)
        return None if d is None else d.row(row)

    def to_json(self) -> dict:
        d: dict = {"name": self.name}
        if self.capture is not None:
            d["capture"] = self.capture
        if self.inputs_n is not None:
            d["inputs_n"] = self.inputs_n
        d.update(source=self.source, status=self.status, notes=list(self.notes), timings=self.timings.to_json())
        if self.input_points is not None:
            d["input_points"] = self.input_points.to_json()
        d["protocol"] = self.split.to_json()
        if self.camera_plot is not None:
            d["camera_plot"] = self.camera_plot
        d["examples"] = {k: dict(v) for k, v in self.examples.items()}
        d.update(self.synthesis.to_json())
        d["densification"] = {r: e.to_json() for r, e in self.densification.items()}
        d.update(self.extra)
        return d

    @classmethod
    def from_json(cls, d: dict) -> SceneResult:
        points = d.get("input_points")
        return cls(
            str(d["name"]),
            d.get("capture"),
            d.get("inputs_n"),
            d.get("source"),
            d.get("status", "ok"),
            list(d.get("notes", [])),
            Timings.from_json(d.get("timings", {})),
            None if points is None else InputPoints.from_json(points),
            SplitInfo.from_json(d.get("protocol", {})),
            d.get("camera_plot"),
            {k: dict(v) for k, v in d.get("examples", {}).items()},
            ViewSynthesisResult.from_json(d),
            {r: ReconResult.from_json(e) for r, e in d.get("densification", {}).items()},
            {k: v for k, v in d.items() if k not in SCENE_KEYS},
        )


@dataclass
class SceneFailure:
    """A run that failed (the others go on): its name, source and one-line error; from ``evaluate`` also
    the capture, N (None when the capture could not be read) and a short traceback (a batch's merged
    failure has neither)."""

    name: str
    source: str | None
    error: str
    capture: str | None = None
    inputs_n: int | None = None
    traceback: str | None = None
    status: Literal["failed"] = "failed"

    @property
    def capture_name(self) -> str:
        return self.capture or self.name

    def to_json(self) -> dict:
        d: dict = {"name": self.name}
        if self.traceback is not None:  # evaluate's record names the capture and N
            d.update(capture=self.capture, inputs_n=self.inputs_n)
        d.update(source=self.source, status=self.status, error=self.error)
        if self.traceback is not None:
            d["traceback"] = self.traceback
        return d

    @classmethod
    def from_json(cls, d: dict) -> SceneFailure:
        return cls(
            str(d.get("name", "?")),
            d.get("source"),
            str(d.get("error", "")),
            d.get("capture"),
            d.get("inputs_n"),
            d.get("traceback"),
        )


def scene_from_json(d: dict) -> SceneResult | SceneFailure:
    """A run read back from results.json: failed, or one that ran (ValueError/KeyError when it is neither)."""
    if not isinstance(d, dict):
        raise ValueError(f"a scene is a JSON object, not {type(d).__name__}")
    return SceneFailure.from_json(d) if d.get("status") == "failed" else SceneResult.from_json(d)
