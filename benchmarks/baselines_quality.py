"""Held-out quality of the classical baselines and the built-in MPI renderer on a dense capture.

Protocol: N evenly spaced frames (np.round(np.linspace(0, n-1, N))) are the only inputs; the
targets are the real frames nearest the midpoints between consecutive inputs (N - 1 of them). Target
images are loaded only to score the outputs, after synthesis; synthesizers see only their poses.

    .venv/bin/python benchmarks/baselines_quality.py [--scene ../shared/data/llff_bird] [--max-side 240]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import torch

from sparself.capture.scene import Frame
from sparself.core.metrics import lpips_status, psnr, ssim, summarize
from sparself.recon.mpi import MpiConfig, fit
from sparself.synthesis.baselines import BASELINES


def read(path: Path, loader: str):
    """auto: sparself.capture.io.read_scene (a COLMAP model wins; depth bounds from its points, 1st/99th
    percentile); llff: poses_bounds.npy, whose bounds are the min near / max far over all views."""
    if loader == "llff":
        from sparself.capture.io.llff import read_llff

        return read_llff(path)
    from sparself.capture.io import read_scene

    return read_scene(path)


def main(argv=None) -> None:
    root = Path(__file__).resolve().parents[1]
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=root.parent / "shared" / "data" / "llff_bird")
    ap.add_argument("--inputs", type=int, default=25)
    ap.add_argument("--max-side", type=int, default=240)
    ap.add_argument("--planes", type=int, default=32)
    ap.add_argument("--methods", default="nearest,blend,flow,planesweep,mpi")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--loader",
        choices=("auto", "llff"),
        default="auto",
        help="auto: read_scene (COLMAP points give tight depth bounds); llff: poses_bounds.npy bounds",
    )
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)

    full = read(args.scene, args.loader).resized(args.max_side)
    n = len(full)
    inp = [int(i) for i in np.round(np.linspace(0, n - 1, args.inputs))]
    tgt = sorted({int(round((a + b) / 2)) for a, b in zip(inp[:-1], inp[1:])} - set(inp))
    # inputs keep their capture index, so "bracketing" is by index; their images are decoded once
    src = full.subset(inp)
    src.frames = [dataclasses.replace(f, image=full.load(i)) for f, i in zip(src.frames, inp)]
    targets = [
        Frame(full.frames[i].name, full.frames[i].pose, full.frames[i].camera_id, full.frames[i].index, None)
        for i in tgt
    ]
    cam = full.cameras[targets[0].camera_id]
    print(f"scene {args.scene.name} (loader {args.loader}): {n} frames, {args.inputs} inputs {inp}")
    print(f"targets ({len(tgt)}): {tgt}; images {cam.width}x{cam.height}; depth bounds {src.depth_bounds()}")
    print(f"LPIPS: {lpips_status()}")

    outputs: dict[str, tuple[np.ndarray, float]] = {}
    for m in args.methods.split(","):
        t0 = time.perf_counter()
        if m == "mpi":
            r = fit(src, MpiConfig(num_planes=args.planes))
            out = np.stack([r.render(tg.pose, full.cameras[tg.camera_id]) for tg in targets])
        else:
            out = BASELINES[m](src, targets, num_planes=args.planes)
        outputs[m] = (out, (time.perf_counter() - t0) / len(targets))

    gts = [full.load(i) for i in tgt]  # ground truth, read only now, for scoring
    print("\n| method | PSNR mean ± std (min..max) | SSIM mean ± std | s/view |\n|---|---|---|---|")
    for m, (out, secs) in outputs.items():
        p = summarize([psnr(o, g) for o, g in zip(out, gts)])
        s = summarize([ssim(o, g) for o, g in zip(out, gts)])
        print(
            f"| {m} | {p['mean']:.2f} ± {p['std']:.2f} ({p['min']:.2f}..{p['max']:.2f}) | "
            f"{s['mean']:.4f} ± {s['std']:.4f} | {secs:.2f} |"
        )
    sys.stdout.flush()


if __name__ == "__main__":
    main()
