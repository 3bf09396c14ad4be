"""The evaluation report: ``report.md`` + ``report.html`` + PNG figures from :mod:`sparself.evaluate` results.

Tables follow the paper's Tables 1-3 (per scene and average, N vs N + synthesized views, with the
change), plus the baselines, the oracle and the share of the oracle's gain. An LPIPS cell shows
"unavailable" whenever the LPIPS weights were not found: a number is never printed for it then.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sparself.evaluation.document import UNAVAILABLE, Doc, avg, change, fmt, lpips_available
from sparself.evaluation.figures import bar_chart, image_grid
from sparself.evaluation.results import (
    EXTRAPOLATED,
    INTERPOLATED,
    NETWORK,
    NETWORK_WEIGHTED,
    finite,
    mean_of,
    share_of_oracle_gain,
)
from sparself.evaluation.results import METRICS as METRIC_NAMES

log = logging.getLogger(__name__)

METRICS = tuple(zip(METRIC_NAMES, ("PSNR (dB) ↑", "SSIM ↑", "LPIPS ↓")))  # (name, table label)


# ---- document model: a list of blocks rendered to both Markdown and HTML ---------------------------


# ---- formatting ------------------------------------------------------------------------------------


# ---- figures ---------------------------------------------------------------------------------------


# ---- the report ------------------------------------------------------------------------------------


def _recon_names(scenes: list[dict]) -> list[str]:
    names: list[str] = []
    for s in scenes:
        for r in s.get("densification", {}):
            if r not in names:
                names.append(r)
    return names


def _label(s: dict, r: str | None = None) -> str:
    """Scene label with its view counts, e.g. 'llff_bird (25→35)'."""
    if r is not None:
        d = s.get("densification", {}).get(r, {})
        n0 = d.get("base", {}).get("views")
        n1 = d.get(NETWORK, {}).get("views")
        if n0 and n1:
            return f"{s['name']} ({n0}→{n1})"
    return s["name"]


def _group_rows(s: dict, label: str) -> list[tuple[str, str | None]]:
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


def _average_rows(cols: dict, cells, ok: list[dict]) -> list[list[str]]:
    """'Average' rows over scenes: of all frames, and per group where two or more scenes have groups (one
    scene's rows would only repeat). ``cols``: group -> one list of values per column; ``cells(values)``:
    the row's cells of one column."""
    grouped = sum(len(_group_rows(s, "")) > 1 for s in ok) > 1
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
class _Ctx:
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


def write_report(results: dict, out_dir: Path) -> tuple[Path, Path]:
    """Write ``report.md``, ``report.html`` and figures (``figures/*.png``) into ``out_dir``."""
    out_dir = Path(out_dir)
    fig_dir = out_dir / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    scenes_all = results.get("scenes", [])
    ok = [s for s in scenes_all if s.get("status") == "ok"]
    c = _Ctx(
        results,
        ok,
        [s for s in scenes_all if s.get("status") != "ok"],
        _recon_names(ok),
        lpips_available(results),
        out_dir,
        fig_dir,
    )
    doc = Doc(None if c.lp else str(results.get("settings", {}).get("lpips_status") or UNAVAILABLE))
    doc.h(1, "sparself evaluation report")
    for section in (
        _protocol_section,
        _not_run_section,
        _densification_tables,
        _recon_comparisons,
        _view_synthesis_tables,
        _figures,
        _examples,
        _batch_section,
        _closing_sections,
    ):
        section(doc, c)
    md = out_dir / "report.md"
    md.write_text(doc.markdown())
    page = out_dir / "report.html"
    page.write_text(doc.html("sparself evaluation report"))
    return md, page


def _protocol_section(doc: Doc, c: _Ctx) -> None:
    settings = c.settings
    doc.h(2, "Protocol")
    doc.p(
        "Every number in this report is measured against real photos that were held out before anything "
        "else happened. Held-out images are never seen by network training, view synthesis or 3D "
        "reconstruction: only their camera poses are used, to render the views that are compared with them; "
        "their pixels are decoded only in the scoring step (scene readers may read image headers for sizes)."
    )
    doc.ul(
        [
            f"Dense captures: every {settings.get('holdout_every', 8)}th interior frame is held out (LLFF-style, "
            f"first and last frames excluded); an extrapolation margin of frames is kept beyond each end (auto: one "
            f"input spacing, at least {settings.get('holdout_every', 8) + 1} frames; never inputs) and "
            f"N = {settings.get('inputs', 25)} evenly spaced frames of the rest "
            f"between the margins are the sparse input. "
            "Planned midpoints are snapped to the real (non-held-out) photo nearest the planned pose in their gap, "
            "planned extrapolations to the nearest one in the margin beyond their end input: the ground truth for "
            "view synthesis at planned poses and the oracle's training images. Held-out frames in the margins are "
            "scored as extrapolated views, apart from the interpolated ones (rows 'extrapolated' / 'interpolated').",
            f"Sparse captures (too few frames for the above, e.g. 16-view Middlebury rings): every "
            f"{settings.get('sparse_holdout_every', 2)}nd interior frame, from the second on, "
            f"is held out and the rest are "
            "the inputs. No oracle is run there (the only real frames between inputs are the held-out ones), and "
            "the planned midpoints lie near held-out poses: the N + synth reconstruction gets synthesized (never "
            "real) views close to the poses it is scored at.",
            f"Densification: each reconstructor is fitted on the N inputs and on N + {settings.get('n_mid', 8)} "
            f"midpoints + {settings.get('n_extra', 2)} extrapolations synthesized by sparself (per seed) and by the "
            "densify baselines; all render the held-out poses.",
            "Oracle: the same reconstruction with the real photos at the snapped planned poses (a planned pose "
            "without a real photo, e.g. an extrapolation with no margin, keeps sparself's seed-0 view). "
            "Share of oracle gain = "
            "(PSNR(N+synth) − PSNR(N)) / (PSNR(oracle) − PSNR(N)).",
            f"sparself numbers are mean ± std over {settings.get('seeds', 3)} network seed(s) of the per-scene means.",
            _points_line(settings.get("points", "capture")),
        ]
    )
    for s in c.ok:
        pts = s.get("input_points")
        pts = f"; sparse points: {pts['points']} (from the {pts['source']})" if pts else ""
        doc.p(
            f"{s['name']}: {s['protocol']['rule']}. Held out: {', '.join(s['protocol']['held_out'])}; "
            f"scored: {len(s['protocol']['scored'])}; inputs: {', '.join(s['protocol']['inputs'])}{pts}."
        )


def _points_line(points: str) -> str:
    """How the reconstructors' sparse points were made (results from before the option used the capture's)."""
    if points == "inputs":
        return (
            "Sparse points (3DGS initial Gaussians, NeRF's depth range): triangulated from the N inputs' photos "
            "alone at their known poses; the capture's own points (made from all its photos, held-out ones "
            "included) are not used. Every row of a scene starts from the same points."
        )
    return (
        "Sparse points: the capture's own, triangulated from all its photos, held-out ones included: through "
        "them the held-out photos reach the reconstructions' starting points (NeRF's depth range, 3DGS "
        "initial Gaussians)."
    )


def _not_run_section(doc: Doc, c: _Ctx) -> None:
    doc.h(2, "Not run")
    nr = dict(c.results.get("not_run", {}))
    nr.setdefault("dietnerf", "not run: needs CLIP weights that cannot be fetched here")
    items = [f"{k}: {v}" for k, v in nr.items()]
    items.append(f"LPIPS: {c.settings.get('lpips_status', 'unavailable')}")
    for s in c.ok:
        items += [f"{s['name']}: {n}" for n in s.get("notes", [])]
        for r, d in s.get("densification", {}).items():
            if d.get("status") == "failed":
                items.append(f"{s['name']} / {r}: failed: {d.get('error')}")
    doc.ul(items)


def _densification_tables(doc: Doc, c: _Ctx) -> None:
    """The paper's Tables 1-3: per scene and on average, N vs N + synthesized views and the change."""
    lp = c.lp
    doc.h(2, "Densification: N input views vs N + synthesized views (the paper's Tables 1–3)")
    for metric, mlabel in METRICS:
        header = ["Scene"]
        for r in c.recons:
            header += [f"{r} N", f"{r} N+synth", f"{r} change"]
        rows: list[list[str]] = []
        cols: dict[str | None, list[tuple[list, list]]] = {}  # group -> per reconstructor (N, N + synth) values
        for s in c.ok:
            for label, g in _group_rows(s, s["name"]):
                row, gcols = [label], cols.setdefault(g, [([], []) for _ in c.recons])
                for r, col in zip(c.recons, gcols):
                    d = s["densification"].get(r, {})
                    a, _ = mean_of(d.get("base"), metric, g)
                    b, sd = mean_of(d.get(NETWORK), metric, g)
                    col[0].append(a)
                    col[1].append(b)
                    row += [fmt(metric, a, lpips_ok=lp), fmt(metric, b, sd, lpips_ok=lp), change(a, b, metric, lp)]
                rows.append(row)

        def cells(col):
            a, b = avg(col[0]), avg(col[1])
            return [fmt(metric, a, lpips_ok=lp), fmt(metric, b, lpips_ok=lp), change(a, b, metric, lp)]

        rows += _average_rows(cols, cells, c.ok)
        doc.h(3, mlabel)
        doc.table(header, rows)


def _share_cell(d: dict, share: str = "oracle_share") -> str:
    sh, gain = finite(d.get(share)), finite(d.get("oracle_gain_db"))
    if str(d.get("instrument", "ok")).startswith("failed"):  # more real photos made it worse
        return f"instrument failed (oracle {gain:+.2f} dB vs N)"
    return f"{100 * sh:.0f}%" if sh is not None else (f"n/a (oracle gain {gain:+.2f} dB)" if gain is not None else "–")


def _group_share_cell(d: dict, group: str, key: str = NETWORK) -> str:
    """The oracle share of ``key`` on one group's frames (where the instrument holds and the gain is measurable)."""
    b, o, s = (mean_of(d.get(k), "psnr", group)[0] for k in ("base", "oracle", key))
    share = share_of_oracle_gain(b, s, o)
    if str(d.get("instrument", "ok")).startswith("failed") or share is None:
        return "–"
    return f"{100 * share:.0f}%"


def _recon_comparisons(doc: Doc, c: _Ctx) -> None:
    """Per reconstructor: N alone, N + sparself, N + each baseline, the oracle, and the oracle share."""
    names = {
        "base": "N only",
        NETWORK: "N + sparself",
        NETWORK_WEIGHTED: "N + sparself, weighted",
        "oracle": "N + real (oracle)",
    }
    for r in c.recons:
        doc.h(3, f"{r}: sparself vs baselines vs oracle (densification)")
        backends = sorted(
            {str(s["densification"][r]["backend"]) for s in c.ok if s["densification"].get(r, {}).get("backend")}
        )
        if backends:
            doc.p(f"{r} ran on: {', '.join(backends)}.")
        keys = []
        for s in c.ok:
            for k in s["densification"].get(r, {}):
                if (
                    k not in keys
                    and isinstance(s["densification"][r][k], dict)
                    and "summary" in s["densification"][r][k]
                ):
                    keys.append(k)
        first = ["base", NETWORK, NETWORK_WEIGHTED]
        order = first + [k for k in keys if k not in first + ["oracle"]] + ["oracle"]
        order = [k for k in order if k in keys]
        shares = [("oracle_share", NETWORK, "share of oracle gain")] + (
            [("oracle_share_weighted", NETWORK_WEIGHTED, "share of oracle gain (weighted)")]
            if NETWORK_WEIGHTED in order
            else []
        )
        for metric, mlabel in METRICS:
            header = (
                ["Scene"]
                + [names.get(k, f"N + {k}") for k in order]
                + ([h for _, _, h in shares] if metric == "psnr" else [])
            )
            rows = []
            for s in c.ok:
                d = s["densification"].get(r, {})
                for label, g in _group_rows(s, _label(s, r)):
                    row = [label] + [fmt(metric, *mean_of(d.get(k), metric, g), lpips_ok=c.lp) for k in order]
                    cells = [_share_cell(d, k) if g is None else _group_share_cell(d, g, net) for k, net, _ in shares]
                    rows.append(row + (cells if metric == "psnr" else []))
            doc.p(mlabel)
            doc.table(header, rows)
        _weight_choices(doc, c, r)


def _weight_choices(doc: Doc, c: _Ctx, r: str) -> None:
    """How 'N + sparself, weighted' chose its synthetic-frame weight: per scene and seed, the weight and the
    PSNR of each tried weight on the held-back input views (never on held-out photos)."""
    items, older = [], False
    for s in c.ok:
        for p in s["densification"].get(r, {}).get(NETWORK_WEIGHTED, {}).get("per_seed", []):
            sel = p.get("selection") or {}
            if "weight" in sel:
                tried = ", ".join(f"{w}: {v:.2f} dB" for w, v in sel.get("validation_psnr", {}).items())
                conf = "confidence maps x " if sel.get("confidence") else "no confidence maps; "
                srcs = sel.get("validation_sources")
                older |= srcs is None  # results from before the validation views were synthesized apart
                made = f"; views synthesized from {len(srcs)} inputs without them" if srcs is not None else ""
                items.append(
                    f"{s['name']} seed {p.get('seed')}: {conf}synthetic-frame weight {sel['weight']} "
                    f"(chosen on seed {sel.get('chosen_on_seed')}; PSNR on held-back inputs "
                    f"{', '.join(sel.get('validation_views', []))}{made}: {tried})"
                )
    if items:
        how = (
            "Where no source count is given, the validation fits used the views synthesized from all inputs, "
            "held-back ones included, which favours larger weights."
            if older
            else "The validation fits' synthesized views are made again by the chosen seed's network from the inputs "
            "without the held-back ones, so their pixels carry none of those views; the network was still trained "
            "on all inputs, the held-back ones among its training targets, which can still favour larger weights."
        )
        doc.p(
            f"{r}, N + sparself, weighted: each pixel of a synthesized view counts its confidence x the "
            "synthetic-frame weight chosen by fitting without the held-back input views named below and scoring "
            f"those. {how}"
        )
        doc.ul(items)


def _methods(ok: list[dict]) -> list[str]:
    methods: list[str] = []
    for s in ok:
        for k, v in s.get("view_synthesis", {}).items():
            if k not in methods and "summary" in v:
                methods.append(k)
    return methods


PLANNED_TABLES = (
    ("midpoints", "View synthesis at midpoint poses (real photos between inputs; dense captures only)"),
    (
        "extrapolations",
        "View synthesis at extrapolated planned poses (t = 1.2 past the end inputs, snapped to "
        "the real photos kept beyond them; dense captures only)",
    ),
)


def _view_synthesis_tables(doc: Doc, c: _Ctx) -> None:
    doc.h(2, "View synthesis at held-out poses (sparself vs baselines)")
    methods, lp = _methods(c.ok), c.lp
    for metric, mlabel in METRICS:
        rows: list[list[str]] = []
        cols: dict[str | None, list[list]] = {}  # group -> per method its values
        for s in c.ok:
            for label, g in _group_rows(s, s["name"]):
                row, gcols = [label], cols.setdefault(g, [[] for _ in methods])
                for m, col in zip(methods, gcols):
                    a, sd = mean_of(s["view_synthesis"].get(m), metric, g)
                    col.append(a)
                    row.append(fmt(metric, a, sd, lpips_ok=lp))
                rows.append(row)
        rows += _average_rows(cols, lambda col: [fmt(metric, avg(col), lpips_ok=lp)], c.ok)
        doc.p(mlabel)
        doc.table(["Scene"] + methods, rows)
    for sec, title in PLANNED_TABLES:
        if any(s.get(sec) for s in c.ok):
            doc.h(3, title)
            for metric, mlabel in METRICS:
                rows = [
                    [s["name"]] + [fmt(metric, *mean_of(s[sec].get(m), metric), lpips_ok=lp) for m in methods]
                    for s in c.ok
                    if s.get(sec)
                ]
                doc.p(mlabel)
                doc.table(["Scene"] + methods, rows)


def _figures(doc: Doc, c: _Ctx) -> None:
    """Bar charts per metric: densification (N vs N + synth per reconstructor) and view synthesis."""
    doc.h(2, "Figures")
    groups, methods = [s["name"] for s in c.ok], _methods(c.ok)
    for metric, mlabel in METRICS:
        if metric == "lpips" and not c.lp:
            continue
        series = {}
        for r in c.recons:
            series[f"{r} N"] = [mean_of(s["densification"].get(r, {}).get("base"), metric)[0] for s in c.ok]
            series[f"{r} N+synth"] = [mean_of(s["densification"].get(r, {}).get(NETWORK), metric)[0] for s in c.ok]
        if groups and series:
            p = c.fig_dir / f"densification_{metric}.png"
            bar_chart(p, f"Densification: {mlabel}", groups, series, mlabel)
            doc.img(str(p.relative_to(c.out_dir)), f"densification {metric}")
        vseries = {m: [mean_of(s["view_synthesis"].get(m), metric)[0] for s in c.ok] for m in methods}
        if groups and vseries:
            p = c.fig_dir / f"view_synthesis_{metric}.png"
            bar_chart(p, f"View synthesis at held-out poses: {mlabel}", groups, vseries, mlabel)
            doc.img(str(p.relative_to(c.out_dir)), f"view synthesis {metric}")


def _examples(doc: Doc, c: _Ctx) -> None:
    """The camera plot and, per example frame, ground truth, predictions and error maps."""
    for s in c.ok:
        if s.get("camera_plot"):
            doc.p(f"{s['name']}: cameras (inputs, planned/synthesized poses, held-out poses)")
            doc.img(s["camera_plot"], f"{s['name']} cameras")
        for frame, imgs in s.get("examples", {}).items():
            p = c.fig_dir / f"grid_{safe_name(s['name'])}_{safe_name(Path(frame).stem)}.png"
            try:
                if image_grid(c.out_dir, p, imgs):
                    doc.p(f"{s['name']}, held-out frame {frame}: ground truth, predictions and error maps")
                    doc.img(str(p.relative_to(c.out_dir)), f"{s['name']} {frame}")
            except Exception as e:  # a broken figure must not lose the tables
                log.warning("image grid for %s failed: %s", frame, e)


def _closing_sections(doc: Doc, c: _Ctx) -> None:
    """Conclusions, failed scenes, settings, versions and timings."""
    doc.h(2, "What the numbers say")
    doc.ul(conclusions(c.results))
    if c.failed:
        doc.h(2, "Scenes that failed")
        doc.table(["Scene", "Error"], [[s.get("name", "?"), str(s.get("error", ""))] for s in c.failed])
    doc.h(2, "Settings")
    flat = {k: v for k, v in c.settings.items() if k != "versions"}
    doc.table(["Setting", "Value"], [[k, str(v)] for k, v in flat.items()])
    doc.table(["Package", "Version"], [[k, str(v)] for k, v in c.settings.get("versions", {}).items()])
    timing_rows = [
        [s["name"]] + [f"{s['timings'].get(k, float('nan')):.1f}" for k in ("network", "baselines", "total")]
        for s in c.ok
    ]
    if timing_rows:
        doc.p("Wall-clock seconds (on a CPU shared with other jobs: inflated by contention).")
        doc.table(["Scene", "network", "baselines", "total"], timing_rows)


def conclusions(results: dict) -> list[str]:
    """Plain sentences: does N + synth beat N (per reconstructor), does sparself beat the baselines."""
    ok = [s for s in results.get("scenes", []) if s.get("status") == "ok"]
    out = []
    for r in _recon_names(ok):
        pairs = [
            (
                mean_of(s["densification"][r].get("base"), "psnr")[0],
                mean_of(s["densification"][r].get(NETWORK), "psnr")[0],
            )
            for s in ok
            if r in s["densification"]
        ]
        known = [(a, b) for a, b in pairs if a is not None and b is not None]
        if not known:
            out.append(f"{r}: no densification result.")
            continue
        wins = sum(b > a for a, b in known)
        d = float(np.mean([b - a for a, b in known]))
        verdict = "beats" if d > 0 else "does not beat"
        out.append(
            f"{r}: N + sparself views {verdict} N views on average by PSNR ({d:+.2f} dB; better on "
            f"{wins} of {len(known)} scenes)."
        )
        for k in sorted(
            {k for s in ok for k, v in s["densification"].get(r, {}).items() if isinstance(v, dict) and "summary" in v}
            - {"base", NETWORK}
        ):
            both = [
                (mean_of(s["densification"][r].get(NETWORK), "psnr")[0], mean_of(s["densification"][r][k], "psnr")[0])
                for s in ok
                if r in s["densification"] and k in s["densification"][r]
            ]
            diffs = [a - b for a, b in both if a is not None and b is not None]
            if diffs and k == NETWORK_WEIGHTED:
                out.append(
                    f"{r}: N + sparself, weighted (confidence x the chosen synthetic-frame weight) vs "
                    f"unweighted: {-float(np.mean(diffs)):+.2f} dB PSNR on average over {len(diffs)} scene(s)."
                )
            elif diffs:
                who = "the real photos (oracle)" if k == "oracle" else f"{k}-synthesized views"
                out.append(
                    f"{r}: N + sparself vs N + {who}: {float(np.mean(diffs)):+.2f} dB PSNR on average "
                    f"over the {len(diffs)} scene(s) where both ran."
                )
    out += [line for s in ok for line in _view_synthesis_conclusions(s)]
    return out or ["No scene produced results."]


def _view_synthesis_conclusions(s: dict) -> list[str]:
    """sparself vs the best baseline at the held-out poses: all of them, then the interpolated and the
    extrapolated ones apart where the scene has both."""
    out, v = [], s.get("view_synthesis", {})
    for group, what in (
        (None, ""),
        (INTERPOLATED, " of interpolated frames"),
        (EXTRAPOLATED, " of extrapolated frames"),
    ):
        net, _ = mean_of(v.get(NETWORK), "psnr", group)
        scored = {k: mean_of(e, "psnr", group)[0] for k, e in v.items() if k != NETWORK and "summary" in e}
        base = {k: x for k, x in scored.items() if x is not None}
        if net is None or not base:
            continue
        best = max(base, key=lambda k: base[k])
        rel = "beats" if net > base[best] else "does not beat"
        out.append(
            f"{s['name']}: view synthesis{what}: sparself ({net:.2f} dB) {rel} the best baseline, {best} "
            f"({base[best]:.2f} dB)."
        )
    return out


def safe_name(name: str) -> str:
    """A file-name-safe version of a scene or frame name."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


# ---- batches (sparself.batch) ------------------------------------------------------------------------


def _spread(vals: list) -> tuple[float | None, float | None]:
    v = [x for x in vals if x is not None]
    return (float(np.mean(v)), float(np.std(v))) if v else (None, None)


def _batch_section(doc: Doc, c: _Ctx) -> None:
    """A batch's results (``sparself batch evaluate``): sparself per capture (mean ± std over seeds), the
    mean ± std over captures, and every unit (capture × seed) with its status and one-line error."""
    if not c.results.get("batch"):
        return
    doc.h(2, "Batch: sparself over captures and seeds")
    for metric, mlabel in METRICS[:2]:
        rows: list[list[str]] = []
        cols: list[list[float | None]] = [[] for _ in range(1 + len(c.recons))]
        for s in c.ok:
            cells = [mean_of(s.get("view_synthesis", {}).get(NETWORK), metric)]
            for r in c.recons:
                d = s.get("densification", {}).get(r, {})
                a, (b, sd) = mean_of(d.get("base"), metric)[0], mean_of(d.get(NETWORK), metric)
                cells.append((None if a is None or b is None else b - a, sd))
            for col, v in zip(cols, cells):
                col.append(v[0])
            rows.append([s["name"], fmt(metric, *cells[0])] + [change(0.0, v, metric, True) for v, _ in cells[1:]])
        rows.append([f"mean ± std over {len(c.ok)} capture(s)"] + [fmt(metric, *_spread(col)) for col in cols])
        doc.p(f"{mlabel} (reconstruction columns: change from N to N + sparself)")
        doc.table(["Capture", "view synthesis"] + [f"{r} N → N+synth" for r in c.recons], rows)
    doc.h(3, "Units")
    doc.table(
        ["Capture", "Seed", "Status", "Seconds", "Error"],
        [
            [
                u["capture"],
                str(u["seed"]),
                u["status"] + (" (earlier run)" if u.get("skipped") else ""),
                f"{u.get('seconds', 0):.1f}",
                u.get("error") or "",
            ]
            for u in c.results["batch"].get("units", [])
        ],
    )


def write_densify_report(results: dict, out_dir: Path) -> tuple[Path, Path]:
    """``report.md`` / ``report.html`` of ``sparself batch densify``: one row per capture, the mean ± std
    over captures, and the captures that failed with their one-line errors."""
    out_dir = Path(out_dir)
    scenes = results.get("scenes", [])
    ok = [s for s in scenes if s.get("status") == "ok"]
    doc = Doc()
    doc.h(1, "sparself batch densify report")
    doc.p(
        f"{len(ok)} of {len(scenes)} capture(s) densified; each output folder is what "
        "`sparself densify CAPTURE --out FOLDER` writes (scene/, plan.json, cameras.png, run/)."
    )
    rows = [
        [
            s["name"],
            s["status"] + (" (earlier run)" if s.get("skipped") else ""),
            *(str(s[k]) if s.get(k) is not None else "–" for k in ("views", "synthesized")),
            f"{s.get('seconds', 0):.1f}",
            s.get("output", "") if s["status"] == "ok" else "",
        ]
        for s in scenes
    ]
    stats = [_spread([s.get(k) for s in ok]) for k in ("views", "synthesized", "seconds")]
    rows.append(
        [f"mean ± std over {len(ok)} capture(s)", ""]
        + [f"{m:.1f} ± {sd:.1f}" if m is not None else "–" for m, sd in stats]
        + [""]
    )
    doc.table(["Capture", "Status", "Input views", "Synthesized", "Seconds", "Output"], rows)
    if results.get("failures"):
        doc.h(2, "Captures that failed")
        doc.table(
            ["Capture", "Seed", "Error"], [[f["capture"], str(f["seed"]), str(f["error"])] for f in results["failures"]]
        )
    doc.h(2, "Settings")
    doc.table(["Package", "Version"], [[k, str(v)] for k, v in results.get("settings", {}).get("versions", {}).items()])
    md, page = out_dir / "report.md", out_dir / "report.html"
    md.write_text(doc.markdown())
    page.write_text(doc.html("sparself batch densify report"))
    return md, page
