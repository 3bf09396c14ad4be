"""The report's document model (blocks rendered to both Markdown and HTML) and how numbers are written in it."""

from __future__ import annotations

import html

import numpy as np

from sparself.evaluation.results import finite
from sparself.evaluation.results_file import Settings


class Doc:
    def __init__(self, why_unavailable: str | None = None) -> None:
        self.blocks: list[tuple] = []
        self.why_unavailable = why_unavailable  # a table of nothing but "unavailable" becomes this line

    def h(self, level: int, text: str) -> None:
        self.blocks.append(("h", level, text))

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def ul(self, items: list[str]) -> None:
        self.blocks.append(("ul", items))

    def table(self, header: list[str], rows: list[list[str]]) -> None:
        cells = [c for r in rows for c in r[1:]]
        if self.why_unavailable and cells and all(c == UNAVAILABLE for c in cells):
            last = self.blocks[-1] if self.blocks else None
            if last is not None and last[0] == "p":  # the table's caption: "LPIPS ↓: unavailable: ..."
                self.blocks[-1] = ("p", f"{last[1]}: {self.why_unavailable}")
            else:
                self.p(self.why_unavailable)
            return
        self.blocks.append(("table", header, rows))

    def img(self, path: str, alt: str) -> None:
        self.blocks.append(("img", path, alt))

    def markdown(self) -> str:
        out = []
        for b in self.blocks:
            if b[0] == "h":
                out.append("#" * b[1] + " " + b[2])
            elif b[0] == "p":
                out.append(b[1])
            elif b[0] == "ul":
                out.append("\n".join(f"- {x}" for x in b[1]))
            elif b[0] == "table":
                header, rows = b[1], b[2]
                lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                lines += ["| " + " | ".join(r) + " |" for r in rows]
                out.append("\n".join(lines))
            elif b[0] == "img":
                out.append(f"![{b[2]}]({b[1]})")
        return "\n\n".join(out) + "\n"

    def html(self, title: str) -> str:
        e = html.escape
        out = [
            f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>",
            "<style>body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}"
            "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:3px 7px;"
            "text-align:right}th{background:#eee}td:first-child{text-align:left}img{max-width:100%}</style>"
            "</head><body>",
        ]
        for b in self.blocks:
            if b[0] == "h":
                out.append(f"<h{b[1]}>{e(b[2])}</h{b[1]}>")
            elif b[0] == "p":
                out.append(f"<p>{e(b[1])}</p>")
            elif b[0] == "ul":
                out.append("<ul>" + "".join(f"<li>{e(x)}</li>" for x in b[1]) + "</ul>")
            elif b[0] == "table":
                rows = "".join("<tr>" + "".join(f"<td>{e(c)}</td>" for c in r) + "</tr>" for r in b[2])
                out.append("<table><tr>" + "".join(f"<th>{e(c)}</th>" for c in b[1]) + "</tr>" + rows + "</table>")
            elif b[0] == "img":
                out.append(f"<p><img src='{e(b[1])}' alt='{e(b[2])}'></p>")
        out.append("</body></html>")
        return "\n".join(out)


def lpips_available(settings: Settings) -> bool:
    return str(settings.option("lpips_status", "")).startswith("available")


def fmt(metric: str, value, std=None, *, lpips_ok: bool = True) -> str:
    """A table cell. LPIPS without weights is always "unavailable"; missing numbers are "–"."""
    if metric == "lpips" and not lpips_ok:
        return UNAVAILABLE
    v = finite(value)
    if v is None:
        return UNAVAILABLE if metric == "lpips" else "–"
    digits = 2 if metric == "psnr" else 3
    s = f"{v:.{digits}f}"
    sd = finite(std)
    if sd is not None:
        s += f" ± {sd:.{digits}f}"
    return s


def avg(vals: list) -> float | None:
    v = [x for x in vals if x is not None]
    return float(np.mean(v)) if v else None


def change(a, b, metric: str, lpips_ok: bool) -> str:
    if metric == "lpips" and not lpips_ok:
        return UNAVAILABLE
    if a is None or b is None:
        return "–"
    d = b - a
    return f"{d:+.{2 if metric == 'psnr' else 3}f}"


UNAVAILABLE = "unavailable"
