"""Which 3DGS recipe to fit with gsplat: each variant chosen on held-back *input* photos, reported on the
evaluation protocol's held-out real photos.

For each capture and N, the protocol's split (``sparself evaluate``'s: every 8th interior frame held out,
N evenly spaced inputs) gives the inputs. A variant is fitted twice per seed: on the inputs without every
5th one from the third (``weighting.validation_inputs``), scored at those held-back inputs (what a user
without held-out photos can measure, and what picks the recipe), and on all N inputs, scored at the
held-out frames (what the pick is worth; never used to pick). Fits run side by side in worker processes.

    python benchmarks/gsplat_recipe.py --capture llff_bird=DATA/llff_bird:9,25 --capture bird=samples/bird:14 \
        --out gsplat_recipe                    # gsplat on CUDA (default); --backend splat: the CPU path

Writes ``OUT/gsplat_recipe.md`` (the table, the pick) and ``OUT/gsplat_recipe.json`` (every fit).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

# name -> SplatConfig overrides; "reference" is gsplat's own recipe (GsplatConfig)
VARIANTS: dict[str, dict[str, Any]] = {
    "reference": {},
    "cpu recipe": {},
    "3x steps": dict(min_steps_per_view=180),
    "up to 30000": dict(max_gaussians=30000),
    "no growth": dict(max_gaussians=3000),
    "sh degree 0": dict(sh_degree=0),
    "20000 initial": dict(init_points=20000, max_gaussians=40000),
    "means lr / 10": dict(lr_means=1.6e-4),
}


@dataclass
class Job:
    capture: str
    path: str
    n: int
    variant: str
    seed: int
    size: int
    backend: str


@dataclass
class Fit:
    capture: str
    n: int
    variant: str
    seed: int
    held_back: float  # PSNR at the held-back inputs, fitted without them
    held_out: float  # PSNR at the protocol's held-out frames, fitted on all inputs
    interpolated: float
    extrapolated: float | None
    gaussians: int
    seconds: float  # both fits


def _fit(job: Job, scene):
    from sparself.recon import get_reconstructor

    if job.variant == "reference":
        from sparself.recon.gsplat import GsplatConfig, fit

        return fit(scene, GsplatConfig(seed=job.seed, progress=False))
    return get_reconstructor(job.backend)(scene, seed=job.seed, progress=False, **VARIANTS[job.variant])


def _psnr(renderer, scene, frames) -> list[float]:
    from sparself.core.metrics import psnr

    return [psnr(renderer.render(scene.frames[i].pose, scene.camera(i)), scene.load(i)) for i in frames]


def _input_points(full, inputs: list[int]):
    """``full`` with points triangulated from the inputs' photos alone, as the protocol fits from (none
    when too few): a capture's own points would carry the held-out photos into every fit."""
    from dataclasses import replace

    from sparself.capture.scene import MIN_POINTS
    from sparself.capture.triangulate import triangulate, with_points

    tri = triangulate(full.subset(inputs))
    if len(tri.points) < MIN_POINTS:
        return replace(full, points=None, point_colors=None, observations={})
    return with_points(full, tri)


def run(job: Job) -> Fit:
    import torch

    from sparself.capture.io import read_scene
    from sparself.evaluation.config import EvalConfig
    from sparself.evaluation.results import EXTRAPOLATED
    from sparself.evaluation.split import make_split
    from sparself.evaluation.weighting import validation_split

    torch.set_num_threads(1)
    full = read_scene(Path(job.path))
    split = make_split(len(full), EvalConfig(inputs=(job.n,)), job.n)
    full = _input_points(full, split.inputs).resized(job.size)
    inputs = full.subset(split.inputs)
    held, rest = validation_split(inputs)
    t0 = time.perf_counter()
    held_back = float(np.mean(_psnr(_fit(job, rest), inputs, held)))
    r = _fit(job, inputs)
    out = _psnr(r, full, split.eval)
    extra = [p for p, i in zip(out, split.eval) if split.group(i) == EXTRAPOLATED]
    inter = [p for p, i in zip(out, split.eval) if split.group(i) != EXTRAPOLATED]
    return Fit(
        job.capture,
        job.n,
        job.variant,
        job.seed,
        held_back,
        float(np.mean(out)),
        float(np.mean(inter)),
        float(np.mean(extra)) if extra else None,
        len(r.gaussians),
        time.perf_counter() - t0,
    )


def _table(fits: list[Fit]) -> tuple[str, str]:
    keys = sorted({(f.capture, f.n) for f in fits})
    variants = [v for v in VARIANTS if any(f.variant == v for f in fits)]
    head = " | ".join(f"{c} {n}: held back / held out" for c, n in keys)
    lines = [f"| recipe | {head} | mean held back | Gaussians | s per variant |", "|" + "---|" * (len(keys) + 4)]
    score = {}
    for v in variants:
        cells, backs = [], []
        for key in keys:
            fs = [f for f in fits if (f.capture, f.n) == key and f.variant == v]
            if not fs:
                cells.append("–")
                continue
            back = statistics.mean(f.held_back for f in fs)
            outs = [f.held_out for f in fs]
            spread = f" ± {statistics.stdev(outs):.2f}" if len(outs) > 1 else ""
            cells.append(f"{back:.2f} / {statistics.mean(outs):.2f}{spread}")
            backs.append(back)
        vf = [f for f in fits if f.variant == v]
        score[v] = statistics.mean(backs) if len(backs) == len(keys) else float("-inf")
        g = statistics.mean(f.gaussians for f in vf)
        s = statistics.mean(f.seconds for f in vf)
        mean = f"{score[v]:.2f}" if backs and len(backs) == len(keys) else "– (not every capture)"
        lines.append(f"| {v} | {' | '.join(cells)} | {mean} | {g:.0f} | {s:.1f} |")
    best = max(score, key=lambda v: score[v])
    return "\n".join(lines), best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", action="append", required=True, help="NAME=PATH:N[,N...]")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--backend", default="gsplat", choices=("gsplat", "splat"))
    ap.add_argument("--jobs", type=int, default=8)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    variants = [v for v in a.variants.split(",") if v != "reference" or a.backend == "gsplat"]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        ap.error(f"unknown variants {unknown}; known: {list(VARIANTS)}")
    specs = []
    for spec in a.capture:
        name, rest = spec.split("=", 1)
        path, ns = rest.rsplit(":", 1)
        specs += [(name, path, int(n)) for n in ns.split(",")]
    # seed by seed, so that a run stopped early has every recipe on every capture for the first seeds
    jobs = [
        Job(name, path, n, v, int(s), a.size, a.backend)
        for s in a.seeds.split(",")
        for name, path, n in specs
        for v in variants
    ]
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    fits: list[Fit] = []
    import multiprocessing as mp
    from concurrent.futures import as_completed

    with ProcessPoolExecutor(a.jobs, mp_context=mp.get_context("spawn")) as pool:
        for future in as_completed([pool.submit(run, job) for job in jobs]):
            try:
                fit = future.result()
            except Exception as e:  # one failed fit must not lose the others
                print(f"failed: {type(e).__name__}: {e}", flush=True)
                continue
            fits.append(fit)
            print(
                f"{fit.capture} {fit.n} {fit.variant} seed {fit.seed}: held back {fit.held_back:.2f}, "
                f"held out {fit.held_out:.2f} dB ({fit.gaussians} Gaussians, {fit.seconds:.1f} s)",
                flush=True,
            )
            (a.out / "gsplat_recipe.json").write_text(json.dumps([asdict(f) for f in fits], indent=1))
    table, best = _table(fits)
    text = (
        f"# 3DGS recipe on {a.backend}, {a.size} px, seeds {a.seeds}\n\n"
        "Each cell: PSNR (dB) at the held-back inputs (fitted without them; picks the recipe) / at the "
        "protocol's held-out frames (fitted on all N inputs; mean ± std over seeds; never used to pick).\n\n"
        f"{table}\n\nPicked on the held-back inputs: **{best}**. Wall time {time.perf_counter() - t0:.0f} s.\n"
    )
    (a.out / "gsplat_recipe.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
