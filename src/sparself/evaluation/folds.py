"""Which held-back input photo may judge which synthesized view.

The self-check holds input photos back and scores fits on them, in folds (:func:`check_folds`). Each view is
judged by the first fold that measures it (:func:`measuring_fold`), at that fold's held-back photos nearest to
it (:func:`view_gains`). Which fold that is depends on where a view's gain is taken
(:data:`~sparself.evaluation.config.Gap`): "own", by a fold that holds back one of its neighbouring photos,
so that the view is judged inside its own gap, where it acts (a gap the check widened to twice its width:
optimistic); "other", by a fold that holds back neither, so that it is judged outside its gap (where,
measured, a view does little). Each mode has its own folds, which together reach every gap between two
inputs.

A view past an end input is judged by a fold of its own that holds both end photos back: no interior
photo is beyond it, so no interior fold can measure it. That fold fits and scores a *stand-in* for it
(:func:`stand_ins`): the same extrapolation made one input further in, which lands between the new end and
the held-back one.
"""

from __future__ import annotations

import numpy as np

from sparself.capture.scene import Frame, Scene
from sparself.evaluation.config import VALIDATION_EVERY, Gap
from sparself.evaluation.weighting import validation_inputs
from sparself.synthesis.plan import planned_frame

ENDS_MIN = 6  # inputs a capture needs for the ends fold: two extrapolate each stand-in after both ends go
TREND_EVERY = 6  # the gap-trend fold holds back a neighbouring pair of inputs every this many


def check_folds(n: int, gap: Gap) -> list[list[int]]:
    """The self-check's folds: positions among n inputs (path order) held back together, the last (from
    ENDS_MIN inputs) holding back both ends, for the views past them.

    With ``gap`` "other" the first is :func:`validation_inputs` and the second, every VALIDATION_EVERY-th
    interior input from the fifth, widens the gaps the first leaves alone, so that between them every gap
    can be measured from outside (:func:`checkable`). With "own" a gap is measured by a fold holding one of
    its two inputs back: the odd positions, alternating between two folds (1, 5, 9, ... and 3, 7, 11, ...),
    hold back one input of every gap and never two neighbours; with n even the last gap's odd input is an
    end, so its other input joins the fold that does not hold its neighbour.

    >>> check_folds(25, "other")
    [[2, 7, 12, 17, 22], [4, 9, 14, 19], [0, 24]]
    >>> check_folds(9, "other")
    [[2, 7], [4], [0, 8]]
    >>> check_folds(9, "own")
    [[1, 5], [3, 7], [0, 8]]
    >>> check_folds(10, "own")
    [[1, 5, 8], [3, 7], [0, 9]]
    """
    ends = [[0, n - 1]] * (n >= ENDS_MIN)
    if gap == "own":
        folds = [list(range(1, n - 1, 4)), list(range(3, n - 1, 4))]
        if n % 2 == 0 and n >= 4:
            folds[int((n - 3) % 4 == 1)].append(n - 2)
        return [f for f in folds if f] + ends
    first = validation_inputs(n)
    second = [p for p in range(4, n - 1, VALIDATION_EVERY) if p not in first]
    return [first] + [second] * bool(second) + ends


def confirm_folds(n: int, gap: Gap) -> list[list[int]]:
    """The interior photos among n inputs that the check's folds (:func:`check_folds` for ``gap``) never hold
    back, alternating between two folds in path order, so that no fold holds back two neighbours: views
    chosen on the check's folds are tested on photos they were not chosen on.

    >>> confirm_folds(25, "own")
    [[2, 6, 10, 14, 18, 22], [4, 8, 12, 16, 20]]
    >>> confirm_folds(10, "own"), confirm_folds(9, "other"), confirm_folds(3, "own")
    ([[2, 6], [4]], [[1, 5], [3, 6]], [])
    """
    used = {p for f in check_folds(n, gap) for p in f}
    left = [p for p in range(1, n - 1) if p not in used]
    return [f for f in (left[0::2], left[1::2]) if f]


def trend_fold(n: int) -> list[int]:
    """The gap-trend fold: interior positions among n inputs held back in neighbouring pairs, every
    TREND_EVERY, so that each pair leaves a gap three inputs wide (the own-gap folds leave two); empty below 4.

    >>> trend_fold(25)
    [1, 2, 7, 8, 13, 14, 19, 20]
    >>> trend_fold(9)
    [1, 2]
    """
    return [q for p in range(1, n - 2, TREND_EVERY) for q in (p, p + 1)]


def one_wide_gain(two: float, three: float) -> float:
    """A view's gain in gaps one input wide (the final fit's), extrapolated linearly in the log of the gap's
    width from its gains in gaps two and three wide: a gain that grows with the width shrinks below it.

    >>> round(one_wide_gain(1.0, 2.0), 3)
    -0.71
    """
    return two - (three - two) * float(np.log(2.0) / np.log(1.5))


def widened_gaps(inputs: Scene, held: list[int]) -> list[tuple[float, float]]:
    """The index interval each held-back position leaves open: from the nearest input kept before it to the
    nearest kept after it (``inputs`` in path order, ``held`` interior)."""
    idx, out = [f.index for f in inputs.frames], []
    for p in held:
        lo, hi = p - 1, p + 1
        while lo in held:
            lo -= 1
        while hi in held:
            hi += 1
        out.append((min(idx[lo], idx[hi]), max(idx[lo], idx[hi])))
    return out


def beyond(inputs: Scene, frames: list[Frame]) -> np.ndarray:
    """(T,) bool: the frames past the first or the last input (``inputs`` in path order)."""
    lo, hi = inputs.frames[0].index, inputs.frames[-1].index
    return np.array([not min(lo, hi) <= f.index <= max(lo, hi) for f in frames], bool)


def stand_ins(inputs: Scene, frames: list[Frame]) -> list[Frame]:
    """``frames`` with each one past an end input replaced by the same extrapolation (the same t) from the
    two inputs next to that end, so that it lies between them and the end input, where a fold holding the
    end back can score it; the others unchanged."""
    idx, n = [f.index for f in inputs.frames], len(inputs)
    out = []
    for f, past in zip(frames, beyond(inputs, frames)):
        if not past:
            out.append(f)
            continue
        a, b, end = (n - 3, n - 2, n - 1) if abs(f.index - idx[-1]) < abs(f.index - idx[0]) else (2, 1, 0)
        t = (f.index - idx[b]) / (idx[end] - idx[b])
        out.append(planned_frame(inputs, a, b, idx[a], idx[b], t))
    return out


def checkable(inputs: Scene, planned: list[Frame], gap: Gap, held: list[int] | None = None) -> np.ndarray:
    """(T,) bool: the planned views outside every held-back input's widened gap, the open interval between
    the indices of the nearest inputs kept on either side of it (:func:`widened_gaps`; ``inputs`` in path
    order; ``held``: the held-back positions, default :func:`validation_inputs`); with ``gap`` "own", the
    views inside one instead.

    A view inside one is measured where the check's fit lacks a photo the final fit has: its gain there is a
    hole the final fit never has ("other": it does not carry over). But a view acts mostly in its own gap,
    and from outside it a view's gain is near zero ("own": measured there, at the price of that optimism).
    Views past the ends are checkable only by a fold holding an end back, and only they are."""
    held = validation_inputs(len(inputs)) if held is None else held
    past = beyond(inputs, planned)
    if {0, len(inputs) - 1} & set(held):
        return past
    gaps = widened_gaps(inputs, held)
    inside = np.array([any(a < f.index < b for a, b in gaps) for f in planned], bool)
    return ~past & (inside if gap == "own" else ~inside)


def measuring_fold(inputs: Scene, planned: list[Frame], gap: Gap) -> np.ndarray:
    """(T,) int: the :func:`check_folds` fold that measures each planned view, the first where it is
    :func:`checkable` (-1: none)."""
    out = np.full(len(planned), -1)
    for k, held in enumerate(check_folds(len(inputs), gap)):
        out[(out < 0) & checkable(inputs, planned, gap, held)] = k
    return out


def nearest_held(inputs: Scene, held: list[int], f: Frame) -> np.ndarray:
    """(len(held),) bool: the held-back positions nearest to ``f`` by index (ties: all of them)."""
    d = np.abs(np.array([inputs.frames[i].index for i in held]) - f.index)
    return np.isclose(d, d.min())


def measuring_photos(inputs: Scene, planned: list[Frame], held: list[int]) -> list[int]:
    """The positions of ``held`` that measure at least one of ``planned`` in :func:`view_gains`: the held-back
    inputs nearest to some view (:func:`nearest_held`), in the order of ``held``."""
    near = np.zeros(len(held), bool)
    for f in planned:
        near |= nearest_held(inputs, held, f)
    return [h for h, k in zip(held, near) if k]


def view_gains(inputs: Scene, planned: list[Frame], gain: np.ndarray, held: list[int] | None = None) -> np.ndarray:
    """Each planned view's gain: the mean of ``gain`` (one per held-back position of ``held``, default
    :func:`validation_inputs`) over the held-back inputs nearest to it by index (ties: all of them)."""
    held = validation_inputs(len(inputs)) if held is None else held
    return np.array([float(np.mean(gain[nearest_held(inputs, held, f)])) for f in planned])
