"""Typed records of the evaluation's results, written by :mod:`sparself.evaluation.evaluate` and read by
:mod:`sparself.evaluation.report` (``results.json`` holds their :meth:`to_json` form).

- :class:`FrameScore`: one rendered frame against its real photo (PSNR, SSIM, LPIPS or None).
- :class:`ScoredSet`: one method's frames of one set (held-out poses, midpoints, or a reconstruction's
  renders), with the seed of a network run and the number of views a reconstruction was fitted on.
- :class:`SeededSets`: the network's sets over seeds, summarised as mean ± std over seeds.

A frame may carry a ``group``: :data:`INTERPOLATED` (between the first and last input in capture order)
or :data:`EXTRAPOLATED` (beyond them). A set whose frames fall in both groups also gets a summary per
group (``groups`` in its JSON), so extrapolated views are reported apart from interpolated ones.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from sparself.core.metrics import summarize

NETWORK = "sparself"  # the CNN-LSTM's name in results and reports
# its densification refit with per-pixel confidence and a synthetic-frame loss weight chosen on input views
NETWORK_WEIGHTED = "sparself_weighted"
NETWORK_CHECKED = "sparself_checked"  # what `densify --recon R` writes: planned where weak, fixed, kept if it pays
NETWORK_FIXED = "sparself_fixed_views"  # the fixer's views at the held-out poses (a view-synthesis score)
METRICS = ("psnr", "ssim", "lpips")
INTERPOLATED, EXTRAPOLATED = "interpolated", "extrapolated"
MIN_ORACLE_GAIN_DB = 0.1  # below this the oracle share is not reported
GROUPS = (INTERPOLATED, EXTRAPOLATED)


@dataclass
class FrameScore:
    frame: str
    index: int
    psnr: float
    ssim: float
    lpips: float | None
    group: str | None = None  # INTERPOLATED or EXTRAPOLATED (None: not grouped)


@dataclass
class ScoredSet:
    frames: list[FrameScore]
    seed: int | None = None
    views: int | None = None

    def summary(self) -> dict:
        return {m: summarize([getattr(f, m) for f in self.frames]) for m in METRICS}

    def only(self, group: str) -> "ScoredSet":
        """The frames of one group, as a set of its own."""
        return ScoredSet([f for f in self.frames if f.group == group], self.seed, self.views)

    def groups(self) -> list[str]:
        """The groups its frames fall in, in :data:`GROUPS` order."""
        return [g for g in GROUPS if any(f.group == g for f in self.frames)]

    def to_json(self) -> dict:
        d: dict = {} if self.seed is None else {"seed": self.seed}
        if self.views is not None:
            d["views"] = self.views
        d.update(frames=[asdict(f) for f in self.frames], summary=self.summary())
        if len(self.groups()) > 1:
            d["groups"] = {g: self.only(g).summary() for g in self.groups()}
        return d


@dataclass
class SeededSets:
    per_seed: list[ScoredSet] = field(default_factory=list)

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

    def to_json(self) -> dict:
        d: dict[str, object] = {"per_seed": [p.to_json() for p in self.per_seed], "summary": self.summary()}
        if self.per_seed and self.per_seed[0].views is not None:
            d["views"] = self.per_seed[0].views
        if len(self.groups()) > 1:
            d["groups"] = {g: self.summary(g) for g in self.groups()}
        return d


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


def mean_of(entry: dict | None, metric: str, group: str | None = None) -> tuple[float | None, float | None]:
    """(mean, std over seeds or None) of a record's summary (the JSON of a ScoredSet or SeededSets), or of
    its summary of one group's frames (None, None when it has no such group)."""
    if not entry or "summary" not in entry:
        return None, None
    summary = entry["summary"] if group is None else entry.get("groups", {}).get(group)
    if summary is None:
        return None, None
    s = summary.get(metric, {})
    seeded = "n_seeds" in s and s.get("n_seeds", 0) > 1
    return finite(s.get("mean")), (finite(s.get("std")) if seeded else None)
