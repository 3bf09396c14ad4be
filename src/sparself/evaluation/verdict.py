"""What the report opens with: a verdict per reconstructor (and per N in a sweep) on whether densifying with
sparself's views helps it, and the PSNR-against-N series of a sweep (``evaluate --inputs 9,12,25``).

Read from the runs' :class:`~sparself.evaluation.scene_results.SceneResult`, old single-N files included:
runs without ``inputs_n`` are judged together, one without ``capture`` is its own capture.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sparself.evaluation.results import (
    BASE,
    NETWORK,
    NETWORK_CHECKED,
    ORACLE,
    ReconResult,
    SeededSets,
    finite,
    mean_of,
    paired_change,
    seed_changes,
    share_of_oracle_gain,
)
from sparself.evaluation.scene_results import SceneResult

HELPS, DOES_NOT_HELP, CANNOT_TELL = "helps", "does not help", "cannot tell"
MIN_CHANGE_DB = 0.1  # a change smaller than this is no change, whatever the spread over seeds
# the rows of the PSNR-against-N plot: (row name in a reconstructor's results, label)
SWEEP_ROWS = (
    (BASE, "N"),
    (NETWORK, "N + sparself"),
    (NETWORK_CHECKED, "N + sparself, checked"),
    ("flow", "N + flow"),
    (ORACLE, "oracle (N + real)"),
)


def n_inputs(s: SceneResult) -> int | None:
    """A run's N as the evaluation asked for it (None in results from before the sweep: one N for all; a
    sparse capture's own input count differs from N and is not grouped by)."""
    return s.inputs_n


def capture(s: SceneResult) -> str:
    return s.capture_name


def decide(change: float | None, spread: float | None) -> str:
    """HELPS when the PSNR gain exceeds both MIN_CHANGE_DB and the spread over seeds; DOES_NOT_HELP when even
    the gain plus the spread stays under MIN_CHANGE_DB; CANNOT_TELL otherwise (the spread covers both)."""
    if change is None:
        return CANNOT_TELL
    spread = spread or 0.0
    if change > MIN_CHANGE_DB and change > spread:
        return HELPS
    if change + spread < MIN_CHANGE_DB:
        return DOES_NOT_HELP
    return CANNOT_TELL


@dataclass
class Verdict:
    """One reconstructor at one N over the captures whose instrument holds: the mean PSNR change from N to
    N + sparself, the mean spread of that change over seeds (each seed's N + sparself against its N, fitted
    with the same reconstruction seed), the mean share of the oracle's gain (where
    measurable) and the captures whose instrument failed (more real photos did not help: not counted)."""

    recon: str
    n: int | None
    word: str
    change_db: float | None = None
    spread_db: float | None = None
    share: float | None = None
    oracle_gain_db: float | None = None
    captures: int = 0
    failed: list[str] = field(default_factory=list)
    shared: int = 0  # captures whose oracle share is measurable (an oracle that gains >= 0.1 dB)
    checked: bool = False  # judged on what densify writes (the checked row), not on every planned view
    seeds: int = 0  # capture seeds judged seed against seed
    below: list[float] = field(default_factory=list)  # their changes below -MIN_CHANGE_DB: worse than N

    def sentence(self, sweep: bool) -> str:
        who = f"{self.recon} at N = {self.n}" if sweep and self.n else self.recon
        failed = (
            f"; instrument failed on {', '.join(self.failed)} (more real photos did not help)" if self.failed else ""
        )
        if self.change_db is None:
            return f"{who}: {self.word}: no capture to judge by{failed}."
        spread = f" ± {self.spread_db:.2f} dB over seeds" if self.spread_db is not None else " (one seed)"
        share = ""
        if self.share is not None:
            on = f" on the {self.shared} capture(s) with one" if self.shared < self.captures else ""
            share = f"; {100 * self.share:.0f} % of the oracle's gain ({self.oracle_gain_db:+.2f} dB){on}"
        what = "N + sparself (checked: what densify writes)" if self.checked else "N + sparself"
        below = (
            f"; below N on {len(self.below)} of {self.seeds} capture seeds (worst {min(self.below):+.2f} dB)"
            if self.below
            else ""
        )
        return (
            f"{who}: {self.word}: {what} {self.change_db:+.2f} dB PSNR over N{spread}{share}{below}; "
            f"{self.captures} capture(s){failed}."
        )


def _mean(vals: list) -> float | None:
    v = [x for x in vals if x is not None]
    return float(np.mean(v)) if v else None


def verdict(scenes: list[SceneResult], recon: str, n: int | None) -> Verdict:
    """The verdict on ``recon`` from the scenes (one N) that ran it: on the checked row (what ``densify --recon``
    writes) where they have it, else on N + every planned view."""
    changes, spreads, shares, gains, failed = [], [], [], [], []
    per_seed: list[float] = []
    row = NETWORK_CHECKED if any(_summarised(s, recon, NETWORK_CHECKED) for s in scenes) else NETWORK
    for s in scenes:
        d = s.densification.get(recon, ReconResult())
        if d.instrument_failed:
            failed.append(capture(s))
            continue
        base = mean_of(d.row(BASE), "psnr")[0]
        net = mean_of(d.row(row), "psnr")[0]
        change, sd = paired_change(d.row(row), d.row(BASE))
        if base is None or net is None or change is None:
            continue
        changes.append(change)
        spreads.append(sd)
        per_seed += seed_changes(d.row(row), d.row(BASE))
        oracle = mean_of(d.row(ORACLE), "psnr")[0]
        share = share_of_oracle_gain(base, net, oracle)
        shares.append(share)
        gains.append(None if share is None or oracle is None else oracle - base)
    change, spread = _mean(changes), _mean(spreads)
    word = decide(change, spread)
    shared = sum(x is not None for x in shares)
    share = _mean(shares)
    return Verdict(
        recon,
        n,
        word,
        change,
        spread,
        share,
        _mean(gains),
        len(changes),
        failed,
        shared,
        checked=row != NETWORK,
        seeds=len(per_seed),
        below=[c for c in per_seed if c < -MIN_CHANGE_DB],
    )


def _summarised(s: SceneResult, recon: str, row: str) -> bool:
    r = s.densification.get(recon, ReconResult()).row(row)
    return isinstance(r, SeededSets) and r.summarized


def verdicts(ok: list[SceneResult], recons: list[str]) -> list[Verdict]:
    """One verdict per reconstructor and N (in ascending N)."""
    out = []
    for r in recons:
        ran = [s for s in ok if r in s.densification]
        for n in sorted({n_inputs(s) or 0 for s in ran}):
            out.append(verdict([s for s in ran if (n_inputs(s) or 0) == n], r, n or None))
    return out


def is_sweep(ok: list[SceneResult]) -> bool:
    """Whether some capture ran at more than one N."""
    ns: dict[str, set] = {}
    for s in ok:
        ns.setdefault(capture(s), set()).add(n_inputs(s))
    return any(len(v) > 1 for v in ns.values())


def sweep_series(
    ok: list[SceneResult], recons: list[str]
) -> dict[str, dict[str, dict[str, tuple[list[int], list[float]]]]]:
    """capture -> reconstructor -> row label -> (N values, mean PSNR at each), for the captures that ran at
    more than one N (rows and points that did not run are left out)."""
    out: dict = {}
    for cap in dict.fromkeys(capture(s) for s in ok):
        runs = sorted((s for s in ok if capture(s) == cap and n_inputs(s)), key=lambda s: n_inputs(s) or 0)
        if len(runs) < 2:
            continue
        for r in recons:
            rows = {}
            for key, label in SWEEP_ROWS:
                pts = [(n_inputs(s), mean_of(s.row(r, key), "psnr")[0]) for s in runs]
                pts = [(n, finite(v)) for n, v in pts if finite(v) is not None]
                if pts:
                    rows[label] = ([n for n, _ in pts], [v for _, v in pts])
            if rows:
                out.setdefault(cap, {})[r] = rows
    return out
