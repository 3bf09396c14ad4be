"""Which frames of a capture are held out, which are the N inputs and which real photos lie at the planned
poses (:func:`make_split`): decided from the frame count alone, before any image is opened."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from sparself.evaluation.config import EvalConfig
from sparself.evaluation.results import EXTRAPOLATED, INTERPOLATED


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

    def group(self, i: float) -> str:
        """EXTRAPOLATED for a frame beyond the first or last input in capture order, else INTERPOLATED."""
        return EXTRAPOLATED if i < self.inputs[0] or i > self.inputs[-1] else INTERPOLATED


def extrapolation_margin(n: int, cfg: EvalConfig) -> int:
    """Frames kept beyond each end input: the setting, or auto: one input spacing ((n-1)/(N+1) frames),
    at least holdout_every + 1 so that a held-out frame lies beyond each end."""
    if cfg.extrapolation_margin is not None:
        return cfg.extrapolation_margin
    return max(round((n - 1) / (cfg.inputs + 1)), cfg.holdout_every + 1)


def dense_split(n: int, held: list[int], rest: list[int], cfg: EvalConfig) -> Split:
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
    rule = (
        f"dense: every {cfg.holdout_every}th interior frame held out ({len(held)}); {len(inputs)} evenly "
        f"spaced inputs from the {len(inside)} remaining frames {inside[0]}..{inside[-1]}{dropped}; "
    )
    if margin:
        rule += (
            f"the {len(margin)} real frames beyond the first and last input (an extrapolation margin of {m} "
            f"frames, never inputs) are ground truth for extrapolated poses and the oracle, and the "
            f"{len(beyond)} held-out frames there are scored as extrapolations; "
        )
    rule += f"the other {len(between)} real frames are ground truth for midpoint poses and the oracle"
    return Split("dense", held, inputs, between, rule, margin)


def make_split(n: int, cfg: EvalConfig) -> Split:
    """The protocol's split of a capture of n frames (see the module docstring)."""
    held = holdout_indices(n, cfg.holdout_every)
    rest = [i for i in range(n) if i not in set(held)]
    if len(rest) >= 2 * cfg.inputs - 1:
        return dense_split(n, held, rest, cfg)
    held = list(range(1, n - 1, cfg.sparse_holdout_every))  # second, fourth, ...: the ends stay inputs
    inputs = [i for i in range(n) if i not in set(held)]
    rule = (
        f"sparse: too few frames for {cfg.inputs} inputs with real frames between them; every "
        f"{cfg.sparse_holdout_every}nd interior frame from the second on held out ({len(held)}), "
        f"the other {len(inputs)} "
        "are the inputs; no oracle (the only real frames between inputs are the held-out ones)"
    )
    return Split("sparse", held, inputs, [], rule)
