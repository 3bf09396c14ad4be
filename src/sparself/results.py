"""Typed records of the evaluation's results, written by :mod:`sparself.evaluate` and read by
:mod:`sparself.report` (``results.json`` holds their :meth:`to_json` form).

- :class:`FrameScore`: one rendered frame against its real photo (PSNR, SSIM, LPIPS or None).
- :class:`ScoredSet`: one method's frames of one set (held-out poses, midpoints, or a reconstruction's
  renders), with the seed of a network run and the number of views a reconstruction was fitted on.
- :class:`SeededSets`: the network's sets over seeds, summarised as mean ± std over seeds.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from .metrics import summarize

NETWORK = "sparself"  # the CNN-LSTM's name in results and reports
METRICS = ("psnr", "ssim", "lpips")


@dataclass
class FrameScore:
    frame: str
    index: int
    psnr: float
    ssim: float
    lpips: float | None


@dataclass
class ScoredSet:
    frames: list[FrameScore]
    seed: int | None = None
    views: int | None = None

    def summary(self) -> dict:
        return {m: summarize([getattr(f, m) for f in self.frames]) for m in METRICS}

    def to_json(self) -> dict:
        d: dict = {} if self.seed is None else {"seed": self.seed}
        if self.views is not None:
            d["views"] = self.views
        d.update(frames=[asdict(f) for f in self.frames], summary=self.summary())
        return d


@dataclass
class SeededSets:
    per_seed: list[ScoredSet] = field(default_factory=list)

    def summary(self) -> dict:
        """Mean +- std over seeds of each seed's per-scene mean."""
        out = {}
        for m in METRICS:
            vals = [s["mean"] for s in (p.summary()[m] for p in self.per_seed) if s["n"] > 0]
            out[m] = {"mean": float(np.mean(vals)) if vals else float("nan"),
                      "std": float(np.std(vals)) if vals else float("nan"), "n_seeds": len(vals)}
        return out

    def to_json(self) -> dict:
        d = {"per_seed": [p.to_json() for p in self.per_seed], "summary": self.summary()}
        if self.per_seed and self.per_seed[0].views is not None:
            d["views"] = self.per_seed[0].views
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


def mean_of(entry: dict | None, metric: str) -> tuple[float | None, float | None]:
    """(mean, std over seeds or None) of a record's summary (the JSON of a ScoredSet or SeededSets)."""
    if not entry or "summary" not in entry:
        return None, None
    s = entry["summary"].get(metric, {})
    seeded = "n_seeds" in s and s.get("n_seeds", 0) > 1
    return finite(s.get("mean")), (finite(s.get("std")) if seeded else None)
