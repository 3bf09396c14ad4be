"""Time of one CPU 3DGS training step at the evaluation's size: the cost every protocol row and self-check fit
is made of.

The evaluation's quick split of a dense capture at N inputs (64 px), one fit of ``--steps`` steps on one thread
(as every fit runs), timed as a whole, then the forward (projection, pairs, compositing, loss) and backward of
the fitted Gaussians at one view, each the median of ``--repeat`` runs: on the compiled path that fits use
(``SplatConfig.compiled``), then on the plain one. Run it alone: a second job on 2 cores
makes any number here meaningless.

    .venv/bin/python benchmarks/splat_step.py ../shared/data/llff_bird --inputs 25 --steps 300
"""

from __future__ import annotations

import argparse
import logging
import statistics
import time
from pathlib import Path

import torch

from sparself.capture.io import read_scene
from sparself.evaluation.config import eval_config
from sparself.evaluation.protocol import start_scene
from sparself.recon import splat
from sparself.recon.common import photometric_loss


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--inputs", type=int, default=25, help="N")
    ap.add_argument("--steps", type=int, default=300, help="steps of the timed fit (the self-check's count)")
    ap.add_argument("--repeat", type=int, default=20, help="runs of the forward / backward timing")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(1)

    cfg = eval_config(quick=True, inputs=(args.inputs,), seeds=1)
    scene = start_scene(read_scene(args.capture), cfg, None, args.inputs).inputs
    cam, pose, truth = scene.camera(0), scene.frames[0].pose, torch.from_numpy(scene.load(0))
    print(f"{args.capture.name}, N = {args.inputs}, {cam.width}x{cam.height} px, torch threads 1")
    for compiled in (True, False):
        if compiled:  # compiling (seconds, once a process) is not a step's cost
            t = time.perf_counter()
            splat.fit(scene, steps=2, min_steps_per_view=0, progress=False, compiled=True)
            print(f"compiled path (compiling and a 2-step fit: {time.perf_counter() - t:.1f} s)")
        else:
            print("plain path")
        t = time.perf_counter()
        fitted = splat.fit(scene, steps=args.steps, min_steps_per_view=0, progress=False, compiled=compiled)
        fit_s = time.perf_counter() - t
        g = splat.Gaussians(**{k: getattr(fitted.gaussians, k).clone().requires_grad_(True) for k in splat._FIELDS})
        forward, backward = [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            img, p = splat.render_gaussians(g, pose, cam, torch.zeros(3), compiled=compiled)
            loss = photometric_loss(img[None], truth[None], 0.2)
            t1 = time.perf_counter()
            loss.backward()
            forward.append(t1 - t0)
            backward.append(time.perf_counter() - t1)
        print(f"- fit of {args.steps} steps: {fit_s:.1f} s ({1000 * fit_s / max(args.steps, 1):.0f} ms a step)")
        print(f"- {len(g)} Gaussians, {len(p.ids)} in view 0")
        fw, bw = 1000 * statistics.median(forward), 1000 * statistics.median(backward)
        print(f"- forward {fw:.1f} ms, backward {bw:.1f} ms")


if __name__ == "__main__":
    main()
