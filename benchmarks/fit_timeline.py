"""Where a run's time goes: every batch of reconstruction fits one ``sparself`` command makes, timed.

    .venv/bin/python benchmarks/fit_timeline.py evaluate samples/bird --out /tmp/t --quick --seeds 1 \\
        --recon 3dgs --splat-steps-per-view 12 --inputs 14 --no-weighted --densify-baselines flow

runs the command as given (same arguments as the ``sparself`` CLI) and then prints one markdown row per batch
of fits (:meth:`sparself.recon.pool.FitPool.run`): when it started, how long it took, the workers it had, and
each scene's view count ('s' marks a scene with synthesized views). Below the table: the share of the run
spent in fits, and the worker-seconds left idle by batches smaller than their pool (a lone fit on a 2-worker
pool leaves one core free while it runs). Time between batches is this process's own work: training,
synthesis, the fixer, scoring.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass


@dataclass
class Batch:
    start: float  # s since the command started
    seconds: float
    workers: int
    scenes: list[str]


def _timed(batches: list[Batch], t0: float):
    from sparself.recon import pool

    plain = pool.FitPool.run

    def run(self, jobs):
        start = time.perf_counter()
        out = plain(self, jobs)
        scenes = [f"{len(sc)}v{'s' * any(f.synthetic for f in sc.frames)}" for _, sc, _ in jobs]
        batches.append(Batch(start - t0, time.perf_counter() - start, self.workers, scenes))
        return out

    return run


def _idle(b: Batch) -> float:
    """Worker-seconds a batch leaves idle: n fits on w workers run in ceil(n / w) rounds (taken as equally long),
    which have room for rounds * w fits."""
    if not b.scenes:
        return 0.0
    rounds = math.ceil(len(b.scenes) / b.workers)
    return b.seconds / rounds * (rounds * b.workers - len(b.scenes))


def table(batches: list[Batch], total: float) -> str:
    rows = ["| start (s) | took (s) | workers | fits | scenes |", "|---|---|---|---|---|"]
    rows += [
        f"| {b.start:.1f} | {b.seconds:.1f} | {b.workers} | {len(b.scenes)} | {' '.join(b.scenes)} |" for b in batches
    ]
    fitting = sum(b.seconds for b in batches)
    idle = sum(_idle(b) for b in batches)
    rows += [
        "",
        f"{len(batches)} batches, {sum(len(b.scenes) for b in batches)} fits: {fitting:.0f} s of {total:.0f} s "
        f"({100 * fitting / max(total, 1e-9):.0f} %) in fits; about {idle:.0f} worker-seconds idle in batches "
        f"smaller than their pool (rounds assumed equally long)",
    ]
    return "\n".join(rows)


def main(argv: list[str]) -> int:
    from sparself import cli
    from sparself.recon import pool

    batches: list[Batch] = []
    t0 = time.perf_counter()
    pool.FitPool.run = _timed(batches, t0)  # only this process: workers fit, the parent times the batches
    rc = cli.main(argv)
    print(table(batches, time.perf_counter() - t0))
    return rc


if __name__ == "__main__":  # the fit workers are spawned and import this file again: only the parent runs it
    sys.exit(main(sys.argv[1:]))
