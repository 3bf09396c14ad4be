"""Throughput of ``sparself batch densify``: captures per hour with 1 and 2 (or more) Ray workers, and the
overhead of Ray against the single-process path on the same manifest.

    python benchmarks/batch.py                       # 4 captures, 1 and 2 workers (~5 min on 2 cores)
    python benchmarks/batch.py --captures 8 --workers 1,2,4,8 --epochs 30   # a bigger machine
    python benchmarks/batch.py --out batch.md --json batch.json

Each capture is a synthetic textured-plane scene (``--views`` views at 96 x 64 px, written as an LLFF/COLMAP
folder). Each row is one fresh process, timed from start to exit (so Python and torch imports, Ray's
start and shutdown, and the combined report are all inside the time):

* ``single process``: one Python process calls ``sparself.pipeline.densify`` on each capture in turn,
  what a user's own loop would do; the reference.
* ``batch --local``: ``sparself batch densify --local`` (no Ray: the batch's bookkeeping and report).
* ``batch, Ray, N workers``: ``sparself batch densify --workers N`` (embedded Ray with N CPUs, one CPU
  thread per task).

Every path runs one torch thread per capture, so that the comparison is of the scheduling and not of
intra-op threads. Overhead of Ray = (time with Ray, 1 worker) - (single process), in seconds and as a
share of the Ray run; the fixed part (Ray start, the workers' imports) shrinks as a share when each
capture takes longer, so the table also gives the share for captures of one minute.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
sys.path.insert(0, str(SRC))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

SINGLE = """
import sys, time, torch
from pathlib import Path
from sparself.pipeline import DensifyConfig, densify
from sparself.synthesis.train import TrainConfig
from sparself.synthesis.plan import PlanConfig
torch.set_num_threads(1)
cfg = DensifyConfig(train=TrainConfig(epochs={epochs}, crop=32, weights="none"), plan=PlanConfig(n_mid=4, n_extra=2),
                    out_size=96)
for line in Path(sys.argv[1]).read_text().split():
    densify(Path(sys.argv[1]).parent / line, Path(sys.argv[2]) / line, cfg)
"""


def make_captures(root: Path, n: int, views: int) -> Path:
    """n synthetic captures (different textures) and a manifest listing them."""
    from dataclasses import replace

    from planescene import plane_scene
    from sparself.capture import io as sio

    for k in range(n):
        sc = plane_scene(xs=tuple(0.08 * i for i in range(views)), seed=k)
        sc = replace(sc, frames=[replace(f, name=f"img{i:02d}.png") for i, f in enumerate(sc.frames)])
        sio.write_scene(sc, root / f"cap{k:02d}")
    manifest = root / "captures.txt"
    manifest.write_text("".join(f"cap{k:02d}\n" for k in range(n)))
    return manifest


def timed(cmd: list[str]) -> float:
    env = {**os.environ, "PYTHONPATH": str(SRC) + os.pathsep + os.environ.get("PYTHONPATH", ""), "OMP_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--captures", type=int, default=4)
    ap.add_argument("--views", type=int, default=10, help="views per synthetic capture")
    ap.add_argument("--epochs", type=int, default=10, help="training epochs per capture")
    ap.add_argument("--workers", default="1,2", help="comma-separated Ray worker counts")
    ap.add_argument("--out", type=Path, default=None, help="also write the table here")
    ap.add_argument("--json", type=Path, default=None, help="raw numbers")
    a = ap.parse_args()
    workers = [int(w) for w in a.workers.split(",")]
    py = sys.executable
    flags = [
        "--epochs",
        str(a.epochs),
        "--crop",
        "32",
        "--weights",
        "none",
        "--n-mid",
        "4",
        "--n-extra",
        "2",
        "--out-size",
        "96",
        "-q",
    ]
    rows: list[tuple[str, float]] = []
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="sparself-bench-batch-") as tmp:
        tmp = Path(tmp)
        manifest = make_captures(tmp / "in", a.captures, a.views)
        rows.append(
            (
                "single process (densify in a loop)",
                timed([py, "-c", SINGLE.format(epochs=a.epochs), str(manifest), str(tmp / "single")]),
            )
        )
        rows.append(
            (
                "batch --local (no Ray)",
                timed(
                    [
                        py,
                        "-m",
                        "sparself.cli",
                        "batch",
                        "densify",
                        str(manifest),
                        "--out",
                        str(tmp / "local"),
                        "--local",
                        *flags,
                    ]
                ),
            )
        )
        for w in workers:
            rows.append(
                (
                    f"batch, Ray, {w} worker{'s' if w > 1 else ''}",
                    timed(
                        [
                            py,
                            "-m",
                            "sparself.cli",
                            "batch",
                            "densify",
                            str(manifest),
                            "--out",
                            str(tmp / f"ray{w}"),
                            "--workers",
                            str(w),
                            *flags,
                        ]
                    ),
                )
            )
    print(table(rows, a, load0, os.getloadavg(), workers))
    if a.out:
        a.out.write_text(table(rows, a, load0, os.getloadavg(), workers) + "\n")
    if a.json:
        a.json.write_text(
            json.dumps(
                {"rows": rows, "captures": a.captures, "views": a.views, "epochs": a.epochs, "cpus": os.cpu_count()},
                indent=1,
            )
        )


def table(rows: list[tuple[str, float]], a, load0, load1, workers: list[int]) -> str:
    single = rows[0][1]
    ray1 = dict(rows).get("batch, Ray, 1 worker")
    out = [
        f"batch densify, {a.captures} synthetic captures ({a.views} views, 96x64 px, {a.epochs} epochs); "
        f"{os.cpu_count()} CPUs, {platform.processor() or platform.machine()}; load average "
        f"{load0[0]:.1f} before, {load1[0]:.1f} after",
        "",
        "| path | wall s | s per capture | captures per hour | vs single process |",
        "|---|---|---|---|---|",
    ]
    for name, t in rows:
        out.append(f"| {name} | {t:.1f} | {t / a.captures:.1f} | {3600 * a.captures / t:.0f} | {single / t:.2f}x |")
    if ray1:
        over = ray1 - single
        per = single / a.captures
        out += [
            "",
            f"Ray overhead (1 worker vs single process): {over:+.1f} s = {100 * over / ray1:.1f} % of the Ray "
            f"run, with {per:.1f} s per capture; for captures of 60 s the same fixed cost would be "
            f"{100 * over / (over + 60 * a.captures):.1f} % of {a.captures} captures",
        ]
    return "\n".join(out)


if __name__ == "__main__":
    main()
