"""The report of a batch: the per-capture table of a batch evaluation, and the report of a batch densify."""

from __future__ import annotations

from pathlib import Path

from sparself.evaluation.document import Doc, change, fmt
from sparself.evaluation.report_context import METRICS, Ctx, spread
from sparself.evaluation.results import (
    BASE,
    NETWORK,
    mean_of,
)
from sparself.evaluation.results_file import DensifyBatchResults


def batch_section(doc: Doc, c: Ctx) -> None:
    """A batch's results (``sparself batch evaluate``): sparself per capture (mean ± std over seeds), the
    mean ± std over captures, and every unit (capture × seed) with its status and one-line error."""
    if c.results.units is None:  # not a batch
        return
    doc.h(2, "Batch: sparself over captures and seeds")
    for metric, mlabel in METRICS[:2]:
        rows: list[list[str]] = []
        cols: list[list[float | None]] = [[] for _ in range(1 + len(c.recons))]
        for s in c.ok:
            cells = [mean_of(s.synthesis.held_out.get(NETWORK), metric)]
            for r in c.recons:
                a, (b, sd) = mean_of(s.row(r, BASE), metric)[0], mean_of(s.row(r, NETWORK), metric)
                cells.append((None if a is None or b is None else b - a, sd))
            for col, v in zip(cols, cells):
                col.append(v[0])
            rows.append([s.name, fmt(metric, *cells[0])] + [change(0.0, v, metric, True) for v, _ in cells[1:]])
        rows.append([f"mean ± std over {len(c.ok)} capture(s)"] + [fmt(metric, *spread(col)) for col in cols])
        doc.p(f"{mlabel} (reconstruction columns: change from N to N + sparself)")
        doc.table(["Capture", "view synthesis"] + [f"{r} N → N+synth" for r in c.recons], rows)
    doc.h(3, "Units")
    doc.table(
        ["Capture", "Seed", "Status", "Seconds", "Error"],
        [
            [
                u.capture,
                str(u.seed),
                u.status + (" (earlier run)" if u.skipped else ""),
                f"{u.seconds:.1f}",
                u.error or "",
            ]
            for u in c.results.units or []
        ],
    )


def write_densify_report(results: DensifyBatchResults, out_dir: Path) -> tuple[Path, Path]:
    """``report.md`` / ``report.html`` of ``sparself batch densify``: one row per capture, the mean ± std
    over captures, and the captures that failed with their one-line errors."""
    out_dir = Path(out_dir)
    scenes, ok = results.units, results.ok
    doc = Doc()
    doc.h(1, "sparself batch densify report")
    doc.p(
        f"{len(ok)} of {len(scenes)} capture(s) densified; each output folder is what "
        "`sparself densify CAPTURE --out FOLDER` writes (scene/, plan.json, cameras.png, run/)."
    )
    rows = [
        [
            str(s.name),
            s.status + (" (earlier run)" if s.skipped else ""),
            *(str(n) if n is not None else "–" for n in (s.views, s.synthesized)),
            f"{s.seconds:.1f}",
            (s.output or "") if s.status == "ok" else "",
        ]
        for s in scenes
    ]
    stats = [spread(v) for v in ([s.views for s in ok], [s.synthesized for s in ok], [s.seconds for s in ok])]
    rows.append(
        [f"mean ± std over {len(ok)} capture(s)", ""]
        + [f"{m:.1f} ± {sd:.1f}" if m is not None else "–" for m, sd in stats]
        + [""]
    )
    doc.table(["Capture", "Status", "Input views", "Synthesized", "Seconds", "Output"], rows)
    if results.failures:
        doc.h(2, "Captures that failed")
        doc.table(["Capture", "Seed", "Error"], [[f.capture, str(f.seed), str(f.error)] for f in results.failures])
    doc.h(2, "Settings")
    doc.table(["Package", "Version"], [[k, str(v)] for k, v in results.versions.items()])
    md, page = out_dir / "report.md", out_dir / "report.html"
    md.write_text(doc.markdown())
    page.write_text(doc.html("sparself batch densify report"))
    return md, page
