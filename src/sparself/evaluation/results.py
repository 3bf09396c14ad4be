"""Typed records of the evaluation's scores, written by :mod:`sparself.evaluation.protocol` and read by
:mod:`sparself.evaluation.report` (``results.json`` holds their :meth:`to_json` form).

- :class:`FrameScore`: one rendered frame against its real photo (PSNR, SSIM, LPIPS or None).
- :class:`ScoredSet`: one method's frames of one set (held-out poses, midpoints, or a reconstruction's
  renders), with the seed of a network run, the number of views a reconstruction was fitted on and the
  decision a seed's fit was made with (:class:`WeightChoice` for "N + sparself, weighted").
- :class:`SeededSets`: the network's sets over seeds, summarised as mean ± std over seeds.
- :class:`RowError`: a method or row that failed, with its one-line error.
- :class:`ReconResult`: one reconstructor on one run: its rows (N alone, N + each method's views, the
  oracle) keyed by row name, the instrument check and the share of the oracle's gain, and the CPU 3DGS's
  :class:`ReachChoice` where several reaches were tried.

A frame may carry a ``group``: :data:`INTERPOLATED` (between the first and last input in capture order)
or :data:`EXTRAPOLATED` (beyond them). A set whose frames fall in both groups also gets a summary per
group (``groups`` in its JSON), so extrapolated views are reported apart from interpolated ones.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Callable, ClassVar, Literal, Protocol

import numpy as np

from sparself.capture.io.dense import SelfCheck
from sparself.core.metrics import summarize

NETWORK = "sparself"  # the CNN-LSTM's name in results and reports
# its densification refit with per-pixel confidence and a synthetic-frame loss weight chosen on input views
NETWORK_WEIGHTED = "sparself_weighted"
NETWORK_CHECKED = "sparself_checked"  # what `densify --recon R` writes: planned where weak, fixed, kept if it pays
# a scene note that qualifies its densified rows: scored frames at the synthesized views' own poses
AT_VIEWS = "at the views' own poses: "
NETWORK_FIXED = "fixer_views"  # the fixer's views at the held-out poses (a view-synthesis score, not a fit)
BASE, ORACLE = "base", "oracle"  # a reconstructor's rows fitted on the N inputs alone / plus real photos
METRICS = ("psnr", "ssim", "lpips")
INTERPOLATED, EXTRAPOLATED = "interpolated", "extrapolated"
MIN_ORACLE_GAIN_DB = 0.1  # below this the oracle share is not reported
GROUPS = (INTERPOLATED, EXTRAPOLATED)
SHARE_KEY = "oracle_share"  # + the row name after NETWORK: "oracle_share", "oracle_share_weighted"


@dataclass
class FrameScore:
    frame: str
    index: int
    psnr: float
    ssim: float
    lpips: float | None
    group: str | None = None  # INTERPOLATED or EXTRAPOLATED (None: not grouped)

    @classmethod
    def from_json(cls, d: dict) -> FrameScore:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


class Decision(Protocol):
    """A JSON-able record of how one seed's fit was made, written beside its scores under ``KEY``."""

    KEY: ClassVar[str]

    def to_json(self) -> dict: ...


@dataclass
class WeightChoice:
    """How "N + sparself, weighted" chose its synthetic-frame weight: the weight, the mean PSNR of each
    tried weight (as written in the results) on the held-back input views, the views synthesized from
    ``validation_sources`` (None in results from before they were synthesized apart), whether confidence
    maps weighted the pixels, and the seed it was chosen on."""

    KEY: ClassVar[str] = "selection"

    weight: float
    validation_psnr: dict[str, float]
    validation_views: list[str]
    validation_sources: list[str] | None
    confidence: bool
    chosen_on_seed: int | None = None

    def to_json(self) -> dict:
        d: dict = {"weight": self.weight, "validation_psnr": dict(self.validation_psnr)}
        d["validation_views"] = list(self.validation_views)
        if self.validation_sources is not None:
            d["validation_sources"] = list(self.validation_sources)
        d["confidence"] = self.confidence
        if self.chosen_on_seed is not None:
            d["chosen_on_seed"] = self.chosen_on_seed
        return d

    @classmethod
    def from_json(cls, d: dict) -> WeightChoice:
        return cls(
            d["weight"],
            dict(d.get("validation_psnr", {})),
            list(d.get("validation_views", [])),
            d.get("validation_sources"),
            bool(d.get("confidence", False)),
            d.get("chosen_on_seed"),
        )


@dataclass
class ReachChoice:
    """How far a capture's CPU 3DGS fits start their random Gaussians past its sparse points, chosen on the
    inputs alone: the reach, the mean PSNR of each tried reach (as written in the results) at the held-back
    input views, and the seed the fits were made with."""

    KEY: ClassVar[str] = "far_reach"

    reach: float
    validation_psnr: dict[str, float]
    validation_views: list[str]
    chosen_on_seed: int

    def to_json(self) -> dict:
        return {
            "reach": self.reach,
            "validation_psnr": dict(self.validation_psnr),
            "validation_views": list(self.validation_views),
            "chosen_on_seed": self.chosen_on_seed,
        }

    @classmethod
    def from_json(cls, d: dict) -> ReachChoice:
        return cls(float(d["reach"]), dict(d["validation_psnr"]), list(d["validation_views"]), int(d["chosen_on_seed"]))


# the decision records a per-seed set may carry, by their JSON key (a new kind of row adds its own here)
DECISIONS: dict[str, Callable[[dict], Decision]] = {
    WeightChoice.KEY: WeightChoice.from_json,
    SelfCheck.KEY: SelfCheck.from_json,
}


@dataclass
class ScoredSet:
    frames: list[FrameScore]
    seed: int | None = None
    views: int | None = None
    decision: Decision | None = None

    has_summary: ClassVar[bool] = True  # a scored set is always summarised (a partial SeededSets is not)

    def summary(self) -> dict:
        return {m: summarize([getattr(f, m) for f in self.frames]) for m in METRICS}

    def only(self, group: str) -> ScoredSet:
        """The frames of one group, as a set of its own."""
        return ScoredSet([f for f in self.frames if f.group == group], self.seed, self.views)

    def groups(self) -> list[str]:
        """The groups its frames fall in, in :data:`GROUPS` order."""
        return [g for g in GROUPS if any(f.group == g for f in self.frames)]

    def mean(self, metric: str, group: str | None = None) -> tuple[float | None, float | None]:
        """(mean, None) of its frames' ``metric`` (of one group's frames: only where it has both groups)."""
        if group is not None and (len(self.groups()) < 2 or group not in self.groups()):
            return None, None
        s = self.summary() if group is None else self.only(group).summary()
        return finite(s[metric]["mean"]), None

    def raw_mean(self, metric: str) -> float:
        """The mean of ``metric`` over its frames, NaN when none is finite."""
        return self.summary()[metric]["mean"]

    def to_json(self) -> dict:
        d: dict = {} if self.seed is None else {"seed": self.seed}
        if self.views is not None:
            d["views"] = self.views
        d.update(frames=[asdict(f) for f in self.frames], summary=self.summary())
        if len(self.groups()) > 1:
            d["groups"] = {g: self.only(g).summary() for g in self.groups()}
        if self.decision is not None:
            d[self.decision.KEY] = self.decision.to_json()
        return d

    @classmethod
    def from_json(cls, d: dict) -> ScoredSet:
        decision = next((read(d[k]) for k, read in DECISIONS.items() if isinstance(d.get(k), dict)), None)
        return cls([FrameScore.from_json(f) for f in d["frames"]], d.get("seed"), d.get("views"), decision)


@dataclass
class SeededSets:
    """The network's sets, one per seed. ``summarized`` is False while a reconstruction's seeds are still
    being fitted (a reconstructor that fails keeps the seeds it finished, without a summary)."""

    per_seed: list[ScoredSet] = field(default_factory=list)
    summarized: bool = True

    @property
    def has_summary(self) -> bool:
        return self.summarized

    def summary(self, group: str | None = None) -> dict:
        """Mean +- std over seeds of each seed's per-scene mean (of one group's frames if given)."""
        out = {}
        for m in METRICS:
            sets = self.per_seed if group is None else [p.only(group) for p in self.per_seed]
            vals = [s["mean"] for s in (p.summary()[m] for p in sets) if s["n"] > 0]
            out[m] = {
                "mean": float(np.mean(vals)) if vals else float("nan"),
                "std": float(np.std(vals)) if vals else float("nan"),
                "n_seeds": len(vals),
            }
        return out

    def groups(self) -> list[str]:
        return [g for g in GROUPS if any(g in p.groups() for p in self.per_seed)]

    @property
    def views(self) -> int | None:
        return self.per_seed[0].views if self.per_seed else None

    def mean(self, metric: str, group: str | None = None) -> tuple[float | None, float | None]:
        """(mean over seeds, std over seeds where more than one seed has frames); of one group's frames
        only where it has both groups; (None, None) while not summarised."""
        if not self.summarized or (group is not None and (len(self.groups()) < 2 or group not in self.groups())):
            return None, None
        s = self.summary(group)[metric]
        return finite(s["mean"]), (finite(s["std"]) if s["n_seeds"] > 1 else None)

    def raw_mean(self, metric: str) -> float:
        return self.summary()[metric]["mean"]

    def to_json(self) -> dict:
        d: dict[str, object] = {"per_seed": [p.to_json() for p in self.per_seed]}
        if not self.summarized:
            return d
        d["summary"] = self.summary()
        if self.views is not None:
            d["views"] = self.views
        if len(self.groups()) > 1:
            d["groups"] = {g: self.summary(g) for g in self.groups()}
        return d

    @classmethod
    def from_json(cls, d: dict) -> SeededSets:
        return cls([ScoredSet.from_json(p) for p in d["per_seed"]], summarized="summary" in d)


@dataclass
class RowError:
    """A method (view synthesis) or a row (densification) that failed; the others stand."""

    error: str
    has_summary: ClassVar[bool] = False

    def mean(self, metric: str, group: str | None = None) -> tuple[float | None, float | None]:
        return None, None

    def to_json(self) -> dict:
        return {"error": self.error}


Row = ScoredSet | SeededSets | RowError  # one method's scores (or its failure) at one set of poses


def row_from_json(d: dict) -> Row:
    """A row from its JSON: per-seed sets, a scored set, or an error; ValueError on anything else."""
    if not isinstance(d, dict):
        raise ValueError(f"a score record is a JSON object, not {type(d).__name__}")
    if "per_seed" in d:
        return SeededSets.from_json(d)
    if "frames" in d:
        return ScoredSet.from_json(d)
    if "error" in d:
        return RowError(str(d["error"]))
    raise ValueError(f"a score record needs frames, per_seed or error, not {sorted(d)}")


def mean_of(row: Row | None, metric: str, group: str | None = None) -> tuple[float | None, float | None]:
    """(mean, std over seeds or None) of a row, or of its frames of one group ((None, None) when it has
    no such group, did not run, failed, or is not summarised)."""
    return (None, None) if row is None else row.mean(metric, group)


def paired_change(row: Row | None, base: Row | None, metric: str = "psnr") -> tuple[float | None, float | None]:
    """(mean, std over seeds or None) of ``row`` minus ``base``: seed against seed where both hold the same
    seeds (the reconstruction seed is shared within a seed, so its noise cancels in the difference), else
    the difference of their means with ``row``'s spread; (None, None) where either has no mean."""
    (r, sd), (b, _) = mean_of(row, metric), mean_of(base, metric)
    if r is None or b is None:
        return None, None
    diffs = seed_changes(row, base, metric)
    if diffs:
        return float(np.mean(diffs)), (float(np.std(diffs)) if len(diffs) > 1 else None)
    return r - b, sd


def seed_changes(row: Row | None, base: Row | None, metric: str = "psnr") -> list[float]:
    """Each seed's ``row`` minus its ``base``, seed against seed (empty where the two do not hold the same
    seeds, or either is not per seed)."""
    if not (isinstance(row, SeededSets) and isinstance(base, SeededSets)):
        return []
    mine = {p.seed: p.raw_mean(metric) for p in row.per_seed}
    theirs = {p.seed: p.raw_mean(metric) for p in base.per_seed}
    if mine.keys() != theirs.keys() or None in mine:
        return []
    return [mine[k] - theirs[k] for k in mine if math.isfinite(mine[k] - theirs[k])]


def is_network_row(name: str) -> bool:
    """Whether a reconstructor's row is fitted on the network's views (``sparself``, ``sparself_*``): those
    get a share of the oracle's gain."""
    return name == NETWORK or name.startswith(NETWORK + "_")


@dataclass
class ReconResult:
    """One reconstructor on one run: its ``rows`` by name in the order they were fitted (BASE, NETWORK,
    each densify baseline, ORACLE, NETWORK_WEIGHTED, ...), the backend it ran on (``fitted``: a fit
    finished, so the backend is known, None where the reconstructor names none), the instrument check
    ("ok", or "failed: ..." when the oracle does not beat N alone), the oracle's gain and each network
    row's share of it (None: not measurable), the status, error and wall-clock seconds."""

    rows: dict[str, Row] = field(default_factory=dict)
    backend: str | None = None
    fitted: bool = False
    oracle_gain_db: float | None = None
    instrument: str | None = None
    shares: dict[str, float | None] = field(default_factory=dict)  # network row name -> share
    status: Literal["ok", "failed"] | None = None
    error: str | None = None
    seconds: float | None = None
    reach: ReachChoice | None = None  # the CPU 3DGS's chosen reach, where several were tried

    def row(self, name: str) -> Row | None:
        return self.rows.get(name)

    @property
    def instrument_failed(self) -> bool:
        return str(self.instrument or "ok").startswith("failed")

    def check_instrument(self) -> None:
        """The instrument check, then the shares: more real photos must not make the reconstructor worse.

        Sets ``instrument`` and ``oracle_gain_db`` where both BASE and ORACLE ran, and the share of each
        summarised network row (None where the oracle gains less than MIN_ORACLE_GAIN_DB or the
        instrument fails)."""
        base, oracle = self.rows.get(BASE), self.rows.get(ORACLE)
        if base is None or oracle is None or isinstance(base, RowError) or isinstance(oracle, RowError):
            return
        b, o = base.raw_mean("psnr"), oracle.raw_mean("psnr")
        self.oracle_gain_db = float(o - b)
        self.instrument = (
            "ok" if o > b else (f"failed: N + real photos {o:.2f} dB is not better than N alone {b:.2f} dB")
        )
        for name, row in self.rows.items():
            if is_network_row(name) and not isinstance(row, RowError) and row.has_summary:
                self.shares[name] = share_of_oracle_gain(b, row.raw_mean("psnr"), o)

    def to_json(self) -> dict:
        d: dict = {"backend": self.backend} if self.fitted else {}
        d.update({name: row.to_json() for name, row in self.rows.items()})
        if self.oracle_gain_db is not None:
            d["oracle_gain_db"] = self.oracle_gain_db
        if self.instrument is not None:
            d["instrument"] = self.instrument
        d.update({SHARE_KEY + name[len(NETWORK) :]: share for name, share in self.shares.items()})
        for k in ("status", "error", "seconds"):
            if getattr(self, k) is not None:
                d[k] = getattr(self, k)
        if self.reach is not None:
            d[ReachChoice.KEY] = self.reach.to_json()
        return d

    @classmethod
    def from_json(cls, d: dict) -> ReconResult:
        shares = {NETWORK + k[len(SHARE_KEY) :]: v for k, v in d.items() if k.startswith(SHARE_KEY)}
        return cls(
            {k: row_from_json(v) for k, v in d.items() if isinstance(v, dict) and k != ReachChoice.KEY},
            d.get("backend"),
            "backend" in d,
            d.get("oracle_gain_db"),
            d.get("instrument"),
            shares,
            d.get("status"),
            d.get("error"),
            d.get("seconds"),
            ReachChoice.from_json(d[ReachChoice.KEY]) if ReachChoice.KEY in d else None,
        )


def finite(v) -> float | None:
    """v as a finite float, else None (missing, NaN, infinite or not a number)."""
    if v is None:
        return None
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def share_of_oracle_gain(base: float | None, synth: float | None, oracle: float | None) -> float | None:
    """(synth - base) / (oracle - base): the part of the oracle's gain that synthesized views capture; None
    when a value is missing or the oracle gains less than MIN_ORACLE_GAIN_DB (a share of a gain the
    oracle does not show is noise, not a fraction)."""
    if base is None or synth is None or oracle is None or oracle - base < MIN_ORACLE_GAIN_DB:
        return None
    return float((synth - base) / (oracle - base))
