"""The report's conclusions in plain sentences, derived from the results alone."""

from __future__ import annotations

import numpy as np

from sparself.evaluation.report_context import recon_names
from sparself.evaluation.results import (
    BASE,
    EXTRAPOLATED,
    INTERPOLATED,
    NETWORK,
    NETWORK_CHECKED,
    NETWORK_FIXED,
    NETWORK_WEIGHTED,
    ORACLE,
    ReconResult,
    mean_of,
)
from sparself.evaluation.results_file import Results
from sparself.evaluation.scene_results import SceneResult


def conclusions(results: Results) -> list[str]:
    """Plain sentences: does N + synth beat N (per reconstructor), does sparself beat the baselines."""
    ok = results.ok
    out = []
    for r in recon_names(ok):
        pairs = [
            (mean_of(s.row(r, BASE), "psnr")[0], mean_of(s.row(r, NETWORK), "psnr")[0])
            for s in ok
            if r in s.densification
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
        ran = [s.densification[r] for s in ok if r in s.densification]
        out += _fixer_sentences(r, ran)
        for k in sorted(
            {k for d in ran for k, row in d.rows.items() if row.has_summary} - {BASE, NETWORK, NETWORK_FIXED}
        ):
            both = [(mean_of(d.row(NETWORK), "psnr")[0], mean_of(d.row(k), "psnr")[0]) for d in ran if k in d.rows]
            diffs = [a - b for a, b in both if a is not None and b is not None]
            if diffs and k == NETWORK_CHECKED:
                out.append(
                    f"{r}: N + sparself, checked (what densify writes: views where {r} is weak, fixed, kept only "
                    f"where they pay on held-back inputs) vs every planned view: {-float(np.mean(diffs)):+.2f} dB "
                    f"PSNR on average over {len(diffs)} scene(s)."
                )
            elif diffs and k == NETWORK_WEIGHTED:
                out.append(
                    f"{r}: N + sparself, weighted (confidence x the chosen synthetic-frame weight) vs "
                    f"unweighted: {-float(np.mean(diffs)):+.2f} dB PSNR on average over {len(diffs)} scene(s)."
                )
            elif diffs:
                who = "the real photos (oracle)" if k == ORACLE else f"{k}-synthesized views"
                out.append(
                    f"{r}: N + sparself vs N + {who}: {float(np.mean(diffs)):+.2f} dB PSNR on average "
                    f"over the {len(diffs)} scene(s) where both ran."
                )
    out += [line for s in ok for line in view_synthesis_conclusions(s)]
    return out or ["No scene produced results."]


def _fixer_sentences(r: str, ran: list[ReconResult]) -> list[str]:
    """The fixer's views at the held-out poses against the N-only render of ``r`` there, where it was used."""
    both = [(mean_of(d.row(NETWORK_FIXED), "psnr")[0], mean_of(d.row(BASE), "psnr")[0]) for d in ran]
    diffs = [a - b for a, b in both if a is not None and b is not None]
    if not diffs:
        return []
    return [
        f"{r}: the fixer's views (network view + {r} render, merged per pixel) vs the render of {r} from N alone "
        f"at the held-out poses: {float(np.mean(diffs)):+.2f} dB PSNR over {len(diffs)} scene(s) where it was used."
    ]


def view_synthesis_conclusions(s: SceneResult) -> list[str]:
    """sparself vs the best baseline at the held-out poses: all of them, then the interpolated and the
    extrapolated ones apart where the scene has both."""
    out, v = [], s.synthesis.held_out
    for group, what in (
        (None, ""),
        (INTERPOLATED, " of interpolated frames"),
        (EXTRAPOLATED, " of extrapolated frames"),
    ):
        net, _ = mean_of(v.get(NETWORK), "psnr", group)
        scored = {k: mean_of(e, "psnr", group)[0] for k, e in v.items() if k != NETWORK and e.has_summary}
        base = {k: x for k, x in scored.items() if x is not None}
        if net is None or not base:
            continue
        best = max(base, key=lambda k: base[k])
        rel = "beats" if net > base[best] else "does not beat"
        out.append(
            f"{s.name}: view synthesis{what}: sparself ({net:.2f} dB) {rel} the best baseline, {best} "
            f"({base[best]:.2f} dB)."
        )
    return out
