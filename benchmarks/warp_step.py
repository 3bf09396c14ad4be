"""Time of one plane sweep (the MPI's, the plane-sweep baseline's and the network's warps), its sampling grid
built row by row against the plain every-pixel-times-every-homography definition, on one thread.

Random homographies near the identity, so most samples fall inside the source as in a real sweep. Each figure
is the median of ``--repeat`` runs; the two grids are also compared (they are the same sums in the same order).
Run it alone: a second job on 2 cores makes any number here meaningless.

    .venv/bin/python benchmarks/warp_step.py --sources 5 --planes 32 --size 64x96
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch

from sparself.core import warp


def _median_ms(f: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return 1000 * statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sources", type=int, default=5, help="source views (the MPI's reference + 4 neighbours)")
    ap.add_argument("--planes", type=int, default=32, help="depth planes (the MPI's default)")
    ap.add_argument("--size", default="64x96", help="HxW of the sources and the sweep")
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    torch.set_num_threads(1)
    h, w = (int(v) for v in args.size.split("x"))
    g = torch.Generator().manual_seed(0)
    src = torch.rand(args.sources, 3, h, w, generator=g)
    H = torch.eye(3).repeat(args.sources, args.planes, 1, 1)
    H = H + 0.01 * torch.randn(args.sources, args.planes, 3, 3, generator=g)

    fast = _median_ms(lambda: warp._sample_grid(H, (h, w), (h, w)), args.repeat)
    plain = _median_ms(lambda: warp._sample_grid_reference(H, (h, w), (h, w)), args.repeat)
    sweep = _median_ms(lambda: warp._warp_many(src, H, (h, w)), args.repeat)  # what the product runs
    same = torch.equal(warp._sample_grid(H, (h, w), (h, w)), warp._sample_grid_reference(H, (h, w), (h, w)))
    print(f"{args.sources} sources x {args.planes} planes at {h}x{w} px, torch threads 1")
    print(f"- sampling grid: row by row {fast:.1f} ms, every pixel times every homography {plain:.1f} ms")
    print(
        f"- a whole sweep (grid and grid_sample): {sweep:.1f} ms; with the plain grid about {sweep - fast + plain:.1f}"
    )
    print(
        f"- the two grids are {'equal to the last bit' if same else 'NOT equal to the last bit (fused multiply-adds?)'}"
    )


if __name__ == "__main__":
    main()
