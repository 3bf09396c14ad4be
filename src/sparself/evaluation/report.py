"""The evaluation report: ``report.md`` + ``report.html`` + PNG figures from the results of
:mod:`sparself.evaluation.evaluate`.

It opens with the verdict per reconstructor (:mod:`sparself.evaluation.verdict`) and, for a sweep over N,
the PSNR-against-N plot; then tables that follow the paper's Tables 1-3 (per scene and average, N vs N +
synthesized views, with the change), plus the baselines, the oracle and the share of the oracle's gain.
Without LPIPS weights no LPIPS table is drawn (the "Not run" list says why, once): a number is never printed
for it then.
"""

from __future__ import annotations

import logging
from pathlib import Path

from sparself.evaluation.batch_report import batch_section
from sparself.evaluation.conclusions import conclusions
from sparself.evaluation.config import PlannedSection
from sparself.evaluation.document import UNAVAILABLE, Doc, avg, change, fmt, lpips_available
from sparself.evaluation.figures import bar_chart, image_grid, sweep_plot
from sparself.evaluation.report_context import (
    Ctx,
    average_rows,
    group_rows,
    group_share_cell,
    method_names,
    recon_names,
    safe_name,
    scene_label,
    share_cell,
)
from sparself.evaluation.results import (
    AT_VIEWS,
    BASE,
    NETWORK,
    NETWORK_CHECKED,
    NETWORK_FIXED,
    NETWORK_WEIGHTED,
    ORACLE,
    ReconResult,
    SeededSets,
    WeightChoice,
    mean_of,
)
from sparself.evaluation.results_file import Results
from sparself.evaluation.scene_results import SceneFailure
from sparself.evaluation.verdict import (
    CANNOT_TELL,
    DOES_NOT_HELP,
    HELPS,
    MIN_CHANGE_DB,
    is_sweep,
    sweep_series,
    verdicts,
)

log = logging.getLogger(__name__)


def write_report(results: Results, out_dir: Path) -> tuple[Path, Path]:
    """Write ``report.md``, ``report.html`` and figures (``figures/*.png``) into ``out_dir``."""
    out_dir = Path(out_dir)
    fig_dir = out_dir / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    ok = results.ok
    c = Ctx(results, ok, results.failed, recon_names(ok), lpips_available(results.settings), out_dir, fig_dir)
    doc = Doc(None if c.lp else str(results.settings.lpips_status or UNAVAILABLE))
    doc.h(1, "sparself evaluation report")
    for section in (
        _verdict_section,
        _protocol_section,
        _not_run_section,
        _densification_tables,
        _recon_comparisons,
        _view_synthesis_tables,
        _figures,
        _examples,
        batch_section,
        _closing_sections,
    ):
        section(doc, c)
    md = out_dir / "report.md"
    md.write_text(doc.markdown())
    page = out_dir / "report.html"
    page.write_text(doc.html("sparself evaluation report"))
    return md, page


def _verdict_section(doc: Doc, c: Ctx) -> None:
    """Does densifying with sparself's views help each reconstructor (per N in a sweep), then the PSNR-vs-N
    plot of a sweep beside it."""
    doc.h(2, "Verdict")
    found = verdicts(c.ok, c.recons)
    if not found:
        doc.p("No reconstructor ran: nothing to judge.")
        return
    doc.p(
        f"Per reconstructor: does N + sparself beat N on the held-out photos? '{HELPS}' when the PSNR gain "
        f"exceeds {MIN_CHANGE_DB} dB and the spread over seeds, '{DOES_NOT_HELP}' when even the gain plus "
        f"that spread stays under {MIN_CHANGE_DB} dB, '{CANNOT_TELL}' between the two or where the instrument "
        "failed (N + real photos, the oracle, not better than N). Details follow."
    )
    sweep = is_sweep(c.ok)
    doc.ul([v.sentence(sweep) for v in found])
    at_views = [f"{s.name}: {n[len(AT_VIEWS) :]}" for s in c.ok for n in s.notes if n.startswith(AT_VIEWS)]
    if at_views:
        doc.p(
            "Where scored held-out frames lie at the synthesized views' own poses, a densified row there measures "
            "the views themselves as much as what they add to the reconstruction; its change at the other frames "
            "is the one that carries over to poses no view was planned at:"
        )
        doc.ul(at_views)
    for cap, panels in sweep_series(c.ok, c.recons).items():
        p = c.fig_dir / f"sweep_{safe_name(cap)}.png"
        try:
            sweep_plot(p, f"{cap}: PSNR on the held-out photos against N", panels)
            doc.img(str(p.relative_to(c.out_dir)), f"{cap} PSNR against N")
        except Exception as e:  # a broken figure must not lose the tables
            log.warning("sweep plot for %s failed: %s", cap, e)


def _protocol_section(doc: Doc, c: Ctx) -> None:
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
            f"Dense captures: every {settings.holdout_every}th interior frame is held out (LLFF-style, "
            f"first and last frames excluded); an extrapolation margin of frames is kept beyond each end (auto: one "
            f"input spacing, at least {settings.holdout_every + 1} frames; never inputs) and "
            f"N = {_inputs_text(settings.inputs)} evenly spaced frames of the rest "
            f"between the margins are the sparse input. "
            "Planned midpoints are snapped to the real (non-held-out) photo nearest the planned pose in their gap, "
            "planned extrapolations to the nearest one in the margin beyond their end input: the ground truth for "
            "view synthesis at planned poses and the oracle's training images. Held-out frames in the margins are "
            "scored as extrapolated views, apart from the interpolated ones (rows 'extrapolated' / 'interpolated').",
            f"Sparse captures (too few frames for the above, e.g. 16-view Middlebury rings): every "
            f"{settings.sparse_holdout_every}nd interior frame, from the second on, "
            f"is held out and the rest are "
            "the inputs. No oracle is run there (the only real frames between inputs are the held-out ones), and "
            "the planned midpoints lie near held-out poses: the N + synth reconstruction gets synthesized (never "
            "real) views close to the poses it is scored at.",
            f"Densification: each reconstructor is fitted on the N inputs and on N + {settings.n_mid} "
            f"midpoints + {settings.n_extra} extrapolations synthesized by sparself (per seed) and by the "
            "densify baselines; all render the held-out poses.",
            "Oracle: the same reconstruction with the real photos at the snapped planned poses (a planned pose "
            "without a real photo, e.g. an extrapolation with no margin, keeps sparself's seed-0 view). "
            "Share of oracle gain = "
            "(PSNR(N+synth) − PSNR(N)) / (PSNR(oracle) − PSNR(N)).",
            f"sparself numbers are mean ± std over {settings.seeds} network seed(s) of the per-scene means. Every "
            "reconstruction of seed k, N alone and the oracle included, is fitted with reconstruction seed "
            "recon_seed + k (a reconstructor without a seed, such as the MPI, fits the rows without sparself's "
            "views once); the verdict's change over N and its spread are taken seed against seed.",
            _points_line(settings.points),
        ]
    )
    for s in c.ok:
        pts = (
            ""
            if s.input_points is None
            else f"; sparse points: {s.input_points.points} (from the {s.input_points.source})"
        )
        doc.p(
            f"{s.name}: {s.split.rule}. Held out: {', '.join(s.split.held_out)}; "
            f"scored: {len(s.split.scored)}; inputs: {', '.join(s.split.inputs)}{pts}."
        )


def _inputs_text(inputs: int | list[int]) -> str:
    """N as the settings record it: one number (results before the sweep) or a list of them."""
    if isinstance(inputs, (list, tuple)):
        more = " (one run, the same held-out frames and margins for every N)" if len(inputs) > 1 else ""
        return ", ".join(str(n) for n in inputs) + more
    return str(inputs)


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


def _not_run_section(doc: Doc, c: Ctx) -> None:
    doc.h(2, "Not run")
    nr = dict(c.results.not_run)
    nr.setdefault("dietnerf", "not run: needs CLIP weights that cannot be fetched here")
    items = [f"{k}: {v}" for k, v in nr.items()]
    items.append(f"LPIPS: {c.settings.option('lpips_status', 'unavailable')}")
    for s in c.ok:
        items += [f"{s.name}: {n}" for n in s.notes if not n.startswith(AT_VIEWS)]  # those go under the verdict
        for r, d in s.densification.items():
            if d.status == "failed":
                items.append(f"{s.name} / {r}: failed: {d.error}")
    doc.ul(items)


def _densification_tables(doc: Doc, c: Ctx) -> None:
    """The paper's Tables 1-3: per scene and on average, N vs N + synthesized views and the change."""
    lp = c.lp
    doc.h(2, "Densification: N input views vs N + synthesized views (the paper's Tables 1–3)")
    for metric, mlabel in c.metrics:
        header = ["Scene"]
        for r in c.recons:
            header += [f"{r} N", f"{r} N+synth", f"{r} change"]
        rows: list[list[str]] = []
        cols: dict[str | None, list[tuple[list, list]]] = {}  # group -> per reconstructor (N, N + synth) values
        for s in c.ok:
            for label, g in group_rows(s, s.name):
                row, gcols = [label], cols.setdefault(g, [([], []) for _ in c.recons])
                for r, col in zip(c.recons, gcols):
                    a, _ = mean_of(s.row(r, BASE), metric, g)
                    b, sd = mean_of(s.row(r, NETWORK), metric, g)
                    col[0].append(a)
                    col[1].append(b)
                    row += [fmt(metric, a, lpips_ok=lp), fmt(metric, b, sd, lpips_ok=lp), change(a, b, metric, lp)]
                rows.append(row)

        def cells(col):
            a, b = avg(col[0]), avg(col[1])
            return [fmt(metric, a, lpips_ok=lp), fmt(metric, b, lpips_ok=lp), change(a, b, metric, lp)]

        rows += average_rows(cols, cells, c.ok)
        doc.h(3, mlabel)
        doc.table(header, rows)


def _recon_comparisons(doc: Doc, c: Ctx) -> None:
    """Per reconstructor: N alone, N + sparself, N + each baseline, the oracle, and the oracle share."""
    names = {
        BASE: "N only",
        NETWORK: "N + sparself",
        NETWORK_WEIGHTED: "N + sparself, weighted",
        NETWORK_CHECKED: "N + sparself, checked (what densify writes)",
        NETWORK_FIXED: "fixer's views (not a fit)",
        ORACLE: "N + real (oracle)",
    }
    for r in c.recons:
        doc.h(3, f"{r}: sparself vs baselines vs oracle (densification)")
        ran = [s.densification[r] for s in c.ok if r in s.densification]
        backends = sorted({str(d.backend) for d in ran if d.backend})
        if backends:
            doc.p(f"{r} ran on: {', '.join(backends)}.")
        keys = []
        for d in ran:
            keys += [k for k, row in d.rows.items() if k not in keys and row.has_summary]
        first = [BASE, NETWORK, NETWORK_WEIGHTED, NETWORK_CHECKED]
        order = first + [k for k in keys if k not in first + [ORACLE]] + [ORACLE]
        order = [k for k in order if k in keys]
        shares = [(NETWORK, "share of oracle gain")] + [
            (row, f"share of oracle gain ({what})")
            for row, what in ((NETWORK_WEIGHTED, "weighted"), (NETWORK_CHECKED, "checked"))
            if row in order
        ]
        for metric, mlabel in c.metrics:
            header = (
                ["Scene"]
                + [names.get(k, f"N + {k}") for k in order]
                + ([h for _, h in shares] if metric == "psnr" else [])
            )
            rows = []
            for s in c.ok:
                d = s.densification.get(r, ReconResult())
                for label, g in group_rows(s, scene_label(s, r)):
                    row = [label] + [fmt(metric, *mean_of(d.row(k), metric, g), lpips_ok=c.lp) for k in order]
                    cells = [share_cell(d, net) if g is None else group_share_cell(d, g, net) for net, _ in shares]
                    rows.append(row + (cells if metric == "psnr" else []))
            doc.p(mlabel)
            doc.table(header, rows)
        _weight_choices(doc, c, r)
        _reach_choices(doc, c, r)


def _reach_choices(doc: Doc, c: Ctx, r: str) -> None:
    """Where the run tried several reaches for the CPU 3DGS's random starting points: per scene, the reach
    it chose and each tried reach's PSNR on the held-back input views (never on held-out photos)."""
    items = []
    for s in c.ok:
        ch = s.densification.get(r, ReconResult()).reach
        if ch is not None:
            tried = ", ".join(f"{float(k):g}x: {v:.2f} dB" for k, v in ch.validation_psnr.items())
            items.append(
                f"{s.name}: {ch.reach:g}x (fits with seed {ch.chosen_on_seed} without the inputs "
                f"{', '.join(ch.validation_views)}, scored on those: {tried})"
            )
    if items:
        doc.p(
            f"{r}: how far past the sparse points' far depth every fit of the scene starts its random Gaussians, "
            "chosen on the inputs alone:"
        )
        doc.ul(items)


def _weight_choices(doc: Doc, c: Ctx, r: str) -> None:
    """How 'N + sparself, weighted' chose its synthetic-frame weight: per scene and seed, the weight and the
    PSNR of each tried weight on the held-back input views (never on held-out photos)."""
    items, older = [], False
    for s in c.ok:
        weighted = s.row(r, NETWORK_WEIGHTED)
        for p in weighted.per_seed if isinstance(weighted, SeededSets) else []:
            sel = p.decision
            if isinstance(sel, WeightChoice):
                tried = ", ".join(f"{w}: {v:.2f} dB" for w, v in sel.validation_psnr.items())
                conf = "confidence maps x " if sel.confidence else "no confidence maps; "
                srcs = sel.validation_sources
                older |= srcs is None  # results from before the validation views were synthesized apart
                made = f"; views synthesized from {len(srcs)} inputs without them" if srcs is not None else ""
                items.append(
                    f"{s.name} seed {p.seed}: {conf}synthetic-frame weight {sel.weight} "
                    f"(chosen on seed {sel.chosen_on_seed}; PSNR on held-back inputs "
                    f"{', '.join(sel.validation_views)}{made}: {tried})"
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


PLANNED_TABLES: tuple[tuple[PlannedSection, str], ...] = (
    ("midpoints", "View synthesis at midpoint poses (real photos between inputs; dense captures only)"),
    (
        "extrapolations",
        "View synthesis at extrapolated planned poses (t = 1.2 past the end inputs, snapped to "
        "the real photos kept beyond them; dense captures only)",
    ),
)


def _view_synthesis_tables(doc: Doc, c: Ctx) -> None:
    doc.h(2, "View synthesis at held-out poses (sparself vs baselines)")
    methods, lp = method_names(c.ok), c.lp
    for metric, mlabel in c.metrics:
        rows: list[list[str]] = []
        cols: dict[str | None, list[list]] = {}  # group -> per method its values
        for s in c.ok:
            for label, g in group_rows(s, s.name):
                row, gcols = [label], cols.setdefault(g, [[] for _ in methods])
                for m, col in zip(methods, gcols):
                    a, sd = mean_of(s.synthesis.held_out.get(m), metric, g)
                    col.append(a)
                    row.append(fmt(metric, a, sd, lpips_ok=lp))
                rows.append(row)
        rows += average_rows(cols, lambda col: [fmt(metric, avg(col), lpips_ok=lp)], c.ok)
        doc.p(mlabel)
        doc.table(["Scene"] + methods, rows)
    for sec, title in PLANNED_TABLES:
        if any(s.synthesis.planned(sec) for s in c.ok):
            doc.h(3, title)
            for metric, mlabel in c.metrics:
                rows = [
                    [s.name]
                    + [fmt(metric, *mean_of(s.synthesis.planned(sec).get(m), metric), lpips_ok=lp) for m in methods]
                    for s in c.ok
                    if s.synthesis.planned(sec)
                ]
                doc.p(mlabel)
                doc.table(["Scene"] + methods, rows)


def _figures(doc: Doc, c: Ctx) -> None:
    """Bar charts per metric: densification (N vs N + synth per reconstructor) and view synthesis."""
    doc.h(2, "Figures")
    groups, methods = [s.name for s in c.ok], method_names(c.ok)
    for metric, mlabel in c.metrics:
        if metric == "lpips" and not c.lp:
            continue
        series = {}
        for r in c.recons:
            series[f"{r} N"] = [mean_of(s.row(r, BASE), metric)[0] for s in c.ok]
            series[f"{r} N+synth"] = [mean_of(s.row(r, NETWORK), metric)[0] for s in c.ok]
        if groups and series:
            p = c.fig_dir / f"densification_{metric}.png"
            bar_chart(p, f"Densification: {mlabel}", groups, series, mlabel)
            doc.img(str(p.relative_to(c.out_dir)), f"densification {metric}")
        vseries = {m: [mean_of(s.synthesis.held_out.get(m), metric)[0] for s in c.ok] for m in methods}
        if groups and vseries:
            p = c.fig_dir / f"view_synthesis_{metric}.png"
            bar_chart(p, f"View synthesis at held-out poses: {mlabel}", groups, vseries, mlabel)
            doc.img(str(p.relative_to(c.out_dir)), f"view synthesis {metric}")


def _examples(doc: Doc, c: Ctx) -> None:
    """The camera plot and, per example frame, ground truth, predictions and error maps."""
    for s in c.ok:
        if s.camera_plot:
            doc.p(f"{s.name}: cameras (inputs, planned/synthesized poses, held-out poses)")
            doc.img(s.camera_plot, f"{s.name} cameras")
        for frame, imgs in s.examples.items():
            p = c.fig_dir / f"grid_{safe_name(s.name)}_{safe_name(Path(frame).stem)}.png"
            try:
                if image_grid(c.out_dir, p, imgs, c.recons):
                    doc.p(
                        f"{s.name}, held-out frame {frame}: ground truth, predictions and error maps (view "
                        "synthesis, then one row per reconstructor)"
                    )
                    doc.img(str(p.relative_to(c.out_dir)), f"{s.name} {frame}")
            except Exception as e:  # a broken figure must not lose the tables
                log.warning("image grid for %s failed: %s", frame, e)


def _closing_sections(doc: Doc, c: Ctx) -> None:
    """Conclusions, failed scenes, settings, versions and timings."""
    doc.h(2, "What the numbers say")
    doc.ul(conclusions(c.results))
    if c.failed:
        doc.h(2, "Scenes that failed")
        doc.table(["Scene", "Error"], [[s.name, s.error if isinstance(s, SceneFailure) else ""] for s in c.failed])
    doc.h(2, "Settings")
    doc.table(["Setting", "Value"], [[k, str(v)] for k, v in c.settings.table()])
    doc.table(["Package", "Version"], [[k, str(v)] for k, v in c.settings.versions.items()])
    nan = float("nan")
    timing_rows = [
        [s.name] + [f"{nan if t is None else t:.1f}" for t in (s.timings.network, s.timings.baselines, s.timings.total)]
        for s in c.ok
    ]
    if timing_rows:
        doc.p("Wall-clock seconds (on a CPU shared with other jobs: inflated by contention).")
        doc.table(["Scene", "network", "baselines", "total"], timing_rows)


# ---- batches (sparself.batch) ------------------------------------------------------------------------
