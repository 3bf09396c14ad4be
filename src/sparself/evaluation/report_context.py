"""What every section of the report reads (:class:`Ctx`) and the small helpers the sections share: scene
labels, row groups, averages, the methods present, share cells."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sparself.evaluation.results import (
    BASE,
    EXTRAPOLATED,
    INTERPOLATED,
    NETWORK,
    ORACLE,
    ReconResult,
    RowError,
    finite,
    mean_of,
    share_of_oracle_gain,
)
from sparself.evaluation.results import METRICS as METRIC_NAMES
from sparself.evaluation.results_file import Results, Settings
from sparself.evaluation.scene_results import SceneFailure, SceneResult
from sparself.evaluation.verdict import is_sweep

METRICS = tuple(zip(METRIC_NAMES, ("PSNR (dB) ↑", "SSIM ↑", "LPIPS ↓")))  # (name, table label)


def recon_names(scenes: list[SceneResult]) -> list[str]:
    names: list[str] = []
    for s in scenes:
        for r in s.densification:
            if r not in names:
                names.append(r)
    return names


def row_views(d: ReconResult | None, row: str) -> int | None:
    """The number of views a reconstructor's row was fitted on (None: it has no such row or says none)."""
    r = None if d is None else d.row(row)
    return None if r is None or isinstance(r, RowError) or not r.has_summary else r.views


def scene_label(s: SceneResult, r: str | None = None) -> str:
    """Scene label with its view counts, e.g. 'llff_bird (25→35)'."""
    if r is not None:
        d = s.densification.get(r)
        n0, n1 = row_views(d, BASE), row_views(d, NETWORK)
        if n0 and n1:
            return f"{s.name} ({n0}→{n1})"
    return s.name


def group_rows(s: SceneResult, label: str) -> list[tuple[str, str | None]]:
    """(row label, group) for a scene's rows: all scored held-out frames, then, where some lie beyond the
    first or last input, the interpolated and the extrapolated ones apart."""
    n_ex = len(s.split.extrapolated)
    if not n_ex:
        return [(label, None)]
    n_in = len(s.split.scored) - n_ex
    return [
        (label, None),
        (f"{s.name}: interpolated ({n_in})", INTERPOLATED),
        (f"{s.name}: extrapolated ({n_ex})", EXTRAPOLATED),
    ]


def average_rows(cols: dict, cells, ok: list[SceneResult]) -> list[list[str]]:
    """'Average' rows over scenes: of all frames, and per group where two or more scenes have groups (one
    scene's rows would only repeat). ``cols``: group -> one list of values per column; ``cells(values)``:
    the row's cells of one column. None in an N sweep: an average over different N means nothing (the verdict
    and the PSNR-against-N plot give each N)."""
    if is_sweep(ok):
        return []
    grouped = sum(len(group_rows(s, "")) > 1 for s in ok) > 1
    rows = []
    for g, label in (
        (None, "Average"),
        (INTERPOLATED, "Average: interpolated"),
        (EXTRAPOLATED, "Average: extrapolated"),
    ):
        if g in cols and (g is None or grouped):
            rows.append([label] + [c for vals in cols[g] for c in cells(vals)])
    return rows


@dataclass
class Ctx:
    """What every section of the report reads: the results, the scenes that ran, the reconstructors,
    whether LPIPS is available, and where figures go."""

    results: Results
    ok: list[SceneResult]
    failed: list[SceneResult | SceneFailure]
    recons: list[str]
    lp: bool
    out_dir: Path
    fig_dir: Path

    @property
    def settings(self) -> Settings:
        return self.results.settings

    @property
    def metrics(self) -> tuple[tuple[str, str], ...]:
        """The tables' metrics: LPIPS only where it was measured (why not is said once, under "Not run")."""
        return METRICS if self.lp else tuple(m for m in METRICS if m[0] != "lpips")


def share_cell(d: ReconResult, row: str = NETWORK) -> str:
    """The share of the oracle's gain of network row ``row`` (or why there is none)."""
    sh, gain = finite(d.shares.get(row)), finite(d.oracle_gain_db)
    if d.instrument_failed:  # more real photos made it worse
        return f"instrument failed (oracle {gain:+.2f} dB vs N)"
    return f"{100 * sh:.0f}%" if sh is not None else (f"n/a (oracle gain {gain:+.2f} dB)" if gain is not None else "–")


def group_share_cell(d: ReconResult, group: str, row: str = NETWORK) -> str:
    """The oracle share of ``row`` on one group's frames (where the instrument holds and the gain is measurable)."""
    b, o, s = (mean_of(d.row(k), "psnr", group)[0] for k in (BASE, ORACLE, row))
    share = share_of_oracle_gain(b, s, o)
    if d.instrument_failed or share is None:
        return "–"
    return f"{100 * share:.0f}%"


def method_names(ok: list[SceneResult]) -> list[str]:
    methods: list[str] = []
    for s in ok:
        for k, v in s.synthesis.held_out.items():
            if k not in methods and v.has_summary:
                methods.append(k)
    return methods


def safe_name(name: str) -> str:
    """A file-name-safe version of a scene or frame name."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def spread(vals: list) -> tuple[float | None, float | None]:
    v = [x for x in vals if x is not None]
    return (float(np.mean(v)), float(np.std(v))) if v else (None, None)
