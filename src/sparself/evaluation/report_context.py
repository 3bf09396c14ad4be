"""What every section of the report reads (:class:`Ctx`) and the small helpers the sections share: scene
labels, row groups, averages, the methods present, share cells."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sparself.evaluation.results import (
    EXTRAPOLATED,
    INTERPOLATED,
    NETWORK,
    finite,
    mean_of,
    share_of_oracle_gain,
)
from sparself.evaluation.results import METRICS as METRIC_NAMES

METRICS = tuple(zip(METRIC_NAMES, ("PSNR (dB) ↑", "SSIM ↑", "LPIPS ↓")))  # (name, table label)


def recon_names(scenes: list[dict]) -> list[str]:
    names: list[str] = []
    for s in scenes:
        for r in s.get("densification", {}):
            if r not in names:
                names.append(r)
    return names


def scene_label(s: dict, r: str | None = None) -> str:
    """Scene label with its view counts, e.g. 'llff_bird (25→35)'."""
    if r is not None:
        d = s.get("densification", {}).get(r, {})
        n0 = d.get("base", {}).get("views")
        n1 = d.get(NETWORK, {}).get("views")
        if n0 and n1:
            return f"{s['name']} ({n0}→{n1})"
    return s["name"]


def group_rows(s: dict, label: str) -> list[tuple[str, str | None]]:
    """(row label, group) for a scene's rows: all scored held-out frames, then, where some lie beyond the
    first or last input, the interpolated and the extrapolated ones apart."""
    n_ex = len(s.get("protocol", {}).get("extrapolated", []))
    if not n_ex:
        return [(label, None)]
    n_in = len(s["protocol"].get("scored", [])) - n_ex
    return [
        (label, None),
        (f"{s['name']}: interpolated ({n_in})", INTERPOLATED),
        (f"{s['name']}: extrapolated ({n_ex})", EXTRAPOLATED),
    ]


def average_rows(cols: dict, cells, ok: list[dict]) -> list[list[str]]:
    """'Average' rows over scenes: of all frames, and per group where two or more scenes have groups (one
    scene's rows would only repeat). ``cols``: group -> one list of values per column; ``cells(values)``:
    the row's cells of one column."""
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

    results: dict
    ok: list[dict]
    failed: list[dict]
    recons: list[str]
    lp: bool
    out_dir: Path
    fig_dir: Path

    @property
    def settings(self) -> dict:
        return self.results.get("settings", {})

    @property
    def metrics(self) -> tuple[tuple[str, str], ...]:
        """The tables' metrics: LPIPS only where it was measured (why not is said once, under "Not run")."""
        return METRICS if self.lp else tuple(m for m in METRICS if m[0] != "lpips")


def share_cell(d: dict, share: str = "oracle_share") -> str:
    sh, gain = finite(d.get(share)), finite(d.get("oracle_gain_db"))
    if str(d.get("instrument", "ok")).startswith("failed"):  # more real photos made it worse
        return f"instrument failed (oracle {gain:+.2f} dB vs N)"
    return f"{100 * sh:.0f}%" if sh is not None else (f"n/a (oracle gain {gain:+.2f} dB)" if gain is not None else "–")


def group_share_cell(d: dict, group: str, key: str = NETWORK) -> str:
    """The oracle share of ``key`` on one group's frames (where the instrument holds and the gain is measurable)."""
    b, o, s = (mean_of(d.get(k), "psnr", group)[0] for k in ("base", "oracle", key))
    share = share_of_oracle_gain(b, s, o)
    if str(d.get("instrument", "ok")).startswith("failed") or share is None:
        return "–"
    return f"{100 * share:.0f}%"


def method_names(ok: list[dict]) -> list[str]:
    methods: list[str] = []
    for s in ok:
        for k, v in s.get("view_synthesis", {}).items():
            if k not in methods and "summary" in v:
                methods.append(k)
    return methods


def safe_name(name: str) -> str:
    """A file-name-safe version of a scene or frame name."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def spread(vals: list) -> tuple[float | None, float | None]:
    v = [x for x in vals if x is not None]
    return (float(np.mean(v)), float(np.std(v))) if v else (None, None)
