"""Is the measuring instrument sound? More *real* photos must never make a reconstruction worse.

    python benchmarks/oracle_check.py                          # llff_bird, 128 px, MPI, 25/35/50/90 views
    python benchmarks/oracle_check.py --recon mpi,3dgs --views 25,35
    python benchmarks/oracle_check.py --mpi-min-baseline 1     # LLFF's rule: sweep neighbours >= D z_min / f away
    python benchmarks/oracle_check.py --densify flow [--mpi-real-sweep]   # evaluate's N / N+flow / oracle

The held-out protocol of ``sparself evaluate``: every 8th interior frame is held out and never used
(not even its pose for fitting); the N-view capture is the evaluate split's 25 evenly spaced inputs plus
real frames spread evenly over the remaining non-held-out ones, each capture the previous one plus
more frames (25 ⊂ 35 ⊂ 50 ⊂ 90). Each reconstructor is fitted on each capture and scored (PSNR) on every
held-out frame. Prints one markdown table and says, per reconstructor, whether PSNR rose at every step.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sparself.capture.io import read_scene  # noqa: E402
from sparself.core.metrics import psnr  # noqa: E402
from sparself.evaluation.split import evenly_spaced, holdout_indices  # noqa: E402
from sparself.recon import get_reconstructor  # noqa: E402


def nested_captures(n_frames: int, views: list[int], inputs: int = 25, every: int = 8) -> tuple[list[int], dict]:
    """(held-out frames, {N: frame indices}) with each capture a superset of the smaller ones."""
    held = holdout_indices(n_frames, every)
    rest = [i for i in range(n_frames) if i not in set(held)]
    cur = evenly_spaced(rest, min(inputs, min(views)))
    caps = {}
    for n in sorted(views):
        others = [i for i in rest if i not in set(cur)]
        cur = sorted(set(cur) | set(evenly_spaced(others, n - len(cur)) if n > len(cur) else []))
        caps[n] = cur
    return held, caps


def densify_check(scene, rname: str, kw: dict, size: int, synth: str) -> dict:
    """``sparself evaluate``'s densification on one capture with the ``synth`` baseline in the network's
    place (cheap, no training): {"N", "N+synth", "oracle", "instrument", "share"} for one reconstructor."""
    from sparself.evaluation.config import EvalConfig
    from sparself.evaluation.protocol import evaluate_scene
    from sparself.evaluation.results import BASE, NETWORK, ORACLE
    from sparself.synthesis.baselines import BASELINES

    fn = BASELINES[synth]
    cfg = EvalConfig(size=size, seeds=1, lpips=False, densify_baselines=(), examples=0, progress=False)
    fit = get_reconstructor(rname)
    res = evaluate_scene(
        scene,
        cfg,
        None,
        network=lambda inputs, seed: fn,
        baselines={},
        reconstructors={rname: lambda sc: fit(sc, **kw)},
    )
    d = res.densification[rname]
    if d.status != "ok":
        raise RuntimeError(d.error)
    m = lambda k: d.rows[k].raw_mean("psnr") if k in d.rows else float("nan")  # noqa: E731 (no oracle: sparse)
    return {
        "N": m(BASE),
        "N+synth": m(NETWORK),
        "oracle": m(ORACLE),
        "instrument": d.instrument,
        "share": d.shares.get(NETWORK),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default=str(ROOT.parent / "shared" / "data" / "llff_bird"))
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--views", default="25,35,50,90")
    ap.add_argument("--recon", default="mpi")
    ap.add_argument(
        "--mpi-min-baseline",
        type=float,
        default=None,
        help="MpiConfig.min_baseline (sweep neighbours' distance floor, units of D z_min / f)",
    )
    ap.add_argument("--max-eval", type=int, default=None, help="score only this many held-out frames")
    ap.add_argument(
        "--densify",
        default=None,
        metavar="BASELINE",
        help="instead: evaluate's N / N + BASELINE views / oracle (N + real) for each reconstructor",
    )
    ap.add_argument("--mpi-real-sweep", action="store_true", help="MpiConfig.sweep_synthetic = False")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    scene = read_scene(Path(args.scene))
    if args.densify:
        kw = {"sweep_synthetic": False} if args.mpi_real_sweep else {}
        for rname in [r.strip() for r in args.recon.split(",") if r.strip()]:
            t0 = time.perf_counter()
            r = densify_check(scene, rname, kw if rname == "mpi" else {}, args.size, args.densify)
            print(
                f"{Path(args.scene).name} {rname}{' real-only sweep' if kw else ''}: N {r['N']:.2f}, "
                f"N + {args.densify} {r['N+synth']:.2f}, oracle {r['oracle']:.2f} dB; instrument "
                f"{r['instrument']}; share {r['share']}; {time.perf_counter() - t0:.0f} s",
                flush=True,
            )
        return 0
    order = sorted(range(len(scene)), key=lambda i: scene.frames[i].index)
    full = scene.subset(order).resized(args.size)
    views = [int(v) for v in args.views.split(",")]
    held, caps = nested_captures(len(full), views)
    if args.max_eval:
        held = evenly_spaced(held, args.max_eval)
    truth = {i: full.load(i) for i in held}
    print(
        f"{Path(args.scene).name} at {args.size} px: {len(full)} frames, {len(held)} held out and scored; "
        f"load {os.getloadavg()[0]:.1f}"
    )
    print("\n| reconstructor | views | PSNR (dB) | std | fit + render (s) |\n|---|---|---|---|---|")
    verdicts = []
    for rname in [r.strip() for r in args.recon.split(",") if r.strip()]:
        kw = {"min_baseline": args.mpi_min_baseline} if rname == "mpi" and args.mpi_min_baseline is not None else {}
        fit = get_reconstructor(rname)
        scores = []
        for n in views:
            t0 = time.perf_counter()
            sub = full.subset(caps[n])
            rend = fit(sub, **kw)
            vals = [psnr(rend.render(full.frames[i].pose, full.camera(i)), truth[i]) for i in held]
            scores.append(float(np.mean(vals)))
            print(
                f"| {rname}{f' min_baseline {args.mpi_min_baseline}' if kw else ''} | {n} | "
                f"{scores[-1]:.2f} | {np.std(vals):.2f} | "
                f"{time.perf_counter() - t0:.0f} |",
                flush=True,
            )
        ok = all(b > a for a, b in zip(scores[:-1], scores[1:]))
        verdicts.append(
            f"{rname}: {'PASS' if ok else 'FAIL'} — PSNR "
            + " → ".join(f"{s:.2f}" for s in scores)
            + f" for {views} real views"
        )
    print()
    print("\n".join(verdicts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
