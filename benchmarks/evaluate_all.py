"""Run ``sparself evaluate`` on every capture in ../shared/data and on the bundled sample (samples/bird).

CPU-sane by default (2 shared cores): 64 px, 2 network seeds (1 in the NeRF run), a short network training,
at most 4 scored
held-out frames per scene, the MPI reconstructor on every scene; the compact NeRF only on the dense
capture(s) named by --nerf-scenes, with a short schedule. Results go to a git-ignored folder
(``out/evaluate_all/<recon>/``: results.json, report.md, report.html, figures). Prints the report paths.

    .venv/bin/python benchmarks/evaluate_all.py [--out out/evaluate_all] [--size 64] [--epochs 2] ...
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
SAMPLE = ROOT / "samples" / "bird"


def scenes() -> list[Path]:
    out = sorted(p for p in DATA.iterdir() if p.is_dir()) if DATA.is_dir() else []
    if SAMPLE.is_dir():
        out.append(SAMPLE)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "evaluate_all")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--epochs", type=int, default=2, help="network epochs (its default, 100, takes hours here)")
    ap.add_argument("--max-eval", type=int, default=4, help="held-out frames scored per scene")
    ap.add_argument("--baselines", default="nearest,blend,flow,planesweep")
    ap.add_argument("--densify-baselines", default="blend,flow")
    ap.add_argument(
        "--nerf-densify-baselines", default="flow", help="densify baselines in the NeRF run (each is a fit)"
    )
    ap.add_argument("--nerf-scenes", default="llff_bird", help="scene folder names also run with the NeRF ('' = none)")
    ap.add_argument(
        "--nerf-steps", type=int, default=600, help="NeRF steps (600: about 2 min a fit at 64 px on 2 busy cores)"
    )
    ap.add_argument("--nerf-seeds", type=int, default=1, help="network seeds in the NeRF run")
    ap.add_argument("--only", default="", help="comma-separated scene folder names to restrict to")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")

    import torch

    from sparself.evaluation.config import EvalConfig
    from sparself.evaluation.evaluate import evaluate

    torch.set_num_threads(2)
    all_scenes = scenes()
    if args.only:
        keep = set(args.only.split(","))
        all_scenes = [p for p in all_scenes if p.name in keep]
    if not all_scenes:
        print(f"no scenes found under {DATA} or {SAMPLE}", file=sys.stderr)
        return 1
    split = lambda s: tuple(x for x in s.split(",") if x)  # noqa: E731
    cfg = EvalConfig(
        size=args.size,
        seeds=args.seeds,
        epochs=args.epochs,
        max_eval=args.max_eval,
        reconstructors=("mpi",),
        baselines=split(args.baselines),
        densify_baselines=split(args.densify_baselines),
        nerf_steps=args.nerf_steps,
    )
    runs = [("mpi", all_scenes, cfg)]
    nerf_scenes = [p for p in all_scenes if p.name in set(split(args.nerf_scenes))]
    if nerf_scenes:
        runs.append(
            (
                "nerf",
                nerf_scenes,
                replace(
                    cfg,
                    reconstructors=("nerf",),
                    seeds=args.nerf_seeds,
                    densify_baselines=split(args.nerf_densify_baselines),
                ),
            )
        )
    for name, paths, c in runs:
        t0 = time.perf_counter()
        out = args.out / name
        res = evaluate(paths, out, c, overwrite=True)
        bad = [s.name for s in res.failed]
        print(
            f"{name}: {len(paths)} scene(s) in {time.perf_counter() - t0:.0f} s -> {out / 'report.md'}"
            + (f" (failed: {', '.join(bad)})" if bad else "")
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
