"""Synthesis quality on held-out REAL frames: CNN–LSTM decoders vs classical baselines.

    python benchmarks/synthesis_quality.py [--captures bird,temple] [--epochs 100] [--threads 1] [--set crop=32]

bird: llff_bird, 25 evenly spaced inputs (np.round(np.linspace(0, 183, 25))) at 1/4 resolution
(136 x 240); ground truth = the real frames nearest the 24 midpoints between consecutive inputs.
temple: middlebury_templeRing (19 consecutive ring views at 160 x 120); every other view is held out
and predicted from the rest. dino / templesparse: middlebury_dinoSparseRing / templeSparseRing (16 ring
views, every other one held out, 160 x 120). Held-out frames are never given to training (their images are not loaded).
Prints a table of mean PSNR / SSIM per method, training and synthesis time (wall and CPU).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from sparself.core.metrics import psnr, ssim
from sparself.synthesis import baselines
from sparself.synthesis.synthesize import synthesize
from sparself.synthesis.train import train
from sparself.synthesis.train_config import TrainConfig

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def capture(name: str, size: int | None = None):
    """-> (sources Scene (resized), targets list[Frame] without images, ground truth (T, H, W, 3), size).
    size: the longer image side (default: the capture's own, above)."""
    from sparself.capture.io import read_scene

    if name == "bird":
        full = read_scene(DATA / "llff_bird")
        src_idx = [int(i) for i in np.round(np.linspace(0, 183, 25))]
        tgt_idx = [int(round((a + b) / 2)) for a, b in zip(src_idx[:-1], src_idx[1:])]
        size_default = 240
    elif name == "temple":
        full = read_scene(DATA / "middlebury_templeRing")
        src_idx = list(range(0, len(full), 2))
        tgt_idx = list(range(1, len(full), 2))
        size_default = 160
    elif name in ("dino", "templesparse"):  # 16-view sparse rings (~22 degrees apart): a wider baseline
        full = read_scene(DATA / ("middlebury_dinoSparseRing" if name == "dino" else "middlebury_templeSparseRing"))
        src_idx = list(range(0, len(full), 2))
        tgt_idx = list(range(1, len(full), 2))
        size_default = 160
    else:
        raise SystemExit(f"unknown capture {name}")
    size = size or size_default
    small = full.resized(size)
    targets = [dataclasses.replace(small.frames[i], path=None, image=None) for i in tgt_idx]
    gt = np.stack([small.load(i) for i in tgt_idx])  # read only for scoring
    return small.subset(src_idx), targets, gt, size


def peak_memory_mb(device: str) -> float:
    """Peak GPU memory since the last call (CUDA), else the process's peak resident memory so far."""
    if device.startswith("cuda"):
        peak = torch.cuda.max_memory_allocated() / 2**20
        torch.cuda.reset_peak_memory_stats()
        return peak
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def score(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    return (
        float(np.mean([psnr(p, g) for p, g in zip(pred, gt)])),
        float(np.mean([ssim(p, g) for p, g in zip(pred, gt)])),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--captures", default="bird,temple")
    ap.add_argument("--methods", default="nearest,blend,planesweep,sweep,sweep-nocontext,fc")
    ap.add_argument("--epochs", type=int, default=100)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--size", type=int, default=None, help="longer image side for every capture (default: each one's)")
    ap.add_argument("--device", default="cpu", help="cpu or cuda, for the network methods")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows here")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a TrainConfig field for the network methods (JSON value), repeatable",
    )
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    overrides = {k: json.loads(v) for k, v in (kv.split("=", 1) for kv in args.set)}
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    rows = []
    print(
        f"{'capture':8} {'method':16} {'PSNR':>6} {'SSIM':>6} {'train s':>8} {'train cpu':>9} {'synth s':>8} "
        f"{'peak MB':>9}"
    )
    for cap in args.captures.split(","):
        sources, targets, gt, size = capture(cap, args.size)
        for m in args.methods.split(","):
            t_train = c_train = 0.0
            if m in ("nearest", "blend", "planesweep", "flow"):
                t0 = time.perf_counter()
                pred = getattr(baselines, m)(sources, targets)
            else:
                cfg = TrainConfig(
                    decoder="fc" if m == "fc" else "sweep",
                    epochs=args.epochs,
                    size=size,
                    context=m != "sweep-nocontext",
                    fc_side=size // 2,
                    device=args.device,
                )
                cfg = dataclasses.replace(cfg, **{k: v for k, v in overrides.items() if m != "fc"})
                with tempfile.TemporaryDirectory() as tmp:
                    t0, c0 = time.perf_counter(), time.process_time()
                    run = train(sources, Path(tmp) / "run", cfg, progress=False)
                    t_train, c_train = time.perf_counter() - t0, time.process_time() - c0
                    t0 = time.perf_counter()
                    pred = synthesize(run, sources, targets)
            t_syn = time.perf_counter() - t0
            peak = peak_memory_mb(args.device)
            p, s = score(pred, gt)
            rows.append(
                {
                    "capture": cap,
                    "method": m,
                    "psnr": p,
                    "ssim": s,
                    "train_s": t_train,
                    "train_cpu_s": c_train,
                    "synth_s": t_syn,
                    "n_targets": len(targets),
                    "hw": list(gt.shape[1:3]),
                    "epochs": args.epochs,
                    "overrides": overrides,
                    "peak_mb": peak,
                }
            )
            print(
                f"{cap:8} {m:16} {p:6.2f} {s:6.3f} {t_train:8.1f} {c_train:9.1f} {t_syn:8.1f} {peak:9.0f}", flush=True
            )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    sys.exit(main())
