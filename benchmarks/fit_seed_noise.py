"""How far does the CPU 3DGS move with its seed alone, and can adding *real* photos lose?

The evaluation's protocol split of a dense capture (quick: 64 px, 6 scored held-out frames), N alone and N +
the real photos at the given frame positions, each fitted at several reconstruction seeds and two step rules
(the evaluation's steps per view, and a fixed step count like the self-check's). A change smaller than what
the seed alone does, measured with one seed, is noise; that is why every row of an evaluation is fitted once
per seed and why the self-check compares its gains with a second seed.

    .venv/bin/python benchmarks/fit_seed_noise.py ../shared/data/llff_bird --inputs 9 --add 22,86,100,124
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

from sparself.capture.io import read_scene
from sparself.core.metrics import psnr
from sparself.evaluation.config import eval_config
from sparself.evaluation.instruments import renders
from sparself.evaluation.protocol import start_scene
from sparself.recon import splat


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--inputs", type=int, default=9, help="N")
    ap.add_argument("--add", default="22,86,100,124", help="frame positions of the real photos added to N")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--steps-per-view", type=int, default=12, help="the evaluation's rule (its --splat-steps-per-view)")
    ap.add_argument("--fixed-steps", type=int, default=300, help="the self-check's rule (its --check-steps); 0: skip")
    ap.add_argument("--view-order", default="epochs", choices=["epochs", "uniform"], help="the fits' view order")
    ap.add_argument("--margin", type=int, default=18, help="the evaluation's --extrapolation-margin")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)

    cfg = eval_config(quick=True, inputs=(args.inputs,), extrapolation_margin=args.margin, seeds=1)
    ev = start_scene(read_scene(args.capture), cfg, None, args.inputs)
    extra = [int(x) for x in args.add.split(",") if x]
    if set(extra) & set(ev.split.eval) or set(extra) & set(ev.split.inputs):
        raise SystemExit(f"--add {args.add}: a held-out frame or an input; held out: {ev.split.eval}")
    truth = [ev.full.load(i) for i in ev.scored]

    def scored(idx: list[int], seed: int, rule: dict) -> tuple[np.ndarray, float]:
        t = time.perf_counter()
        r = splat.fit(ev.full.subset(sorted(idx)), seed=seed, progress=False, view_order=args.view_order, **rule)
        got = np.array([psnr(a, b) for a, b in zip(renders(r, ev.full, ev.targets), truth)])
        return got, time.perf_counter() - t

    rules = {f"{args.steps_per_view} steps per view": dict(steps=0, min_steps_per_view=args.steps_per_view)}
    if args.fixed_steps:
        rules[f"{args.fixed_steps} steps"] = dict(steps=args.fixed_steps, min_steps_per_view=0)
    print(
        f"{args.capture.name}, N = {args.inputs}, + real photos at {extra}; PSNR (dB) on {len(truth)} held-out frames; "
        f"view order {args.view_order}"
    )
    print("\n| fit | seed | N alone | N + real | change | per frame | seconds |\n|---|---|---|---|---|---|---|")
    for name, rule in rules.items():
        for seed in range(args.seeds):
            base, tb = scored(list(ev.split.inputs), seed, rule)
            more, tm = scored(list(ev.split.inputs) + extra, seed, rule)
            frames = " ".join(f"{d:+.1f}" for d in more - base)
            print(
                f"| {name} | {seed} | {base.mean():.2f} | {more.mean():.2f} | {more.mean() - base.mean():+.2f} "
                f"| {frames} | {tb:.0f} + {tm:.0f} |"
            )


if __name__ == "__main__":
    main()
