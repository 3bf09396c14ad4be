"""Speed and memory of sparself, printed as a markdown table beside the targets and the paper's figures.

    python benchmarks/run.py                 # default: fits in 10 minutes on 2 CPU cores
    python benchmarks/run.py --quick         # a smoke run (~3 min): fewer epochs, no SfM
    python benchmarks/run.py --full          # the real thing: every epoch of the default config is run
    python benchmarks/run.py --out table.md  # also write the table to a file

What it measures (each stage in a fresh Python process, so "peak memory" is that stage's own peak:
``ru_maxrss`` of the process on CPU, ``torch.cuda.max_memory_allocated`` on GPU):

* **train**: the CNN–LSTM synthesizer trained leave-one-out on 25 views of ``llff_bird`` (every 7th of the
  184 frames) with the default :class:`sparself.synthesis.train.TrainConfig`. CPU: images at 128 px, the CPU defaults
  (frozen 64 px backbone, 32 px crops, 100 epochs). GPU: the paper's setting, 224 px backbone input
  fine-tuned end to end, 100 epochs. Unless ``--full``, fewer epochs are run and the total is extrapolated
  (setup + measured checkpoint cost + epochs x the median steady epoch; the table says so).
* **infer**: the trained run synthesizes the default plan's 10 novel poses (8 midpoints + 2
  extrapolations) from the 25 sources: one call per view, and all 10 in one batched call.
* **poses**: pycolmap pose recovery (``sparself.capture.sfm.recover_poses``, the product's default options:
  deterministic, one thread) on the same 25 photos at their native 960 x 544 (<= 1000 px).
* **scale**: planning, one training epoch and 10-view synthesis with 25, 50 and 100 source views
  (``llff_bird`` subsets, or synthetic views without the data), with the cost ratio against 25 views
  beside the view ratio: cost must grow no worse than linearly.

Without ``../shared/data/llff_bird`` the train/infer/scale stages use a synthetic textured-plane scene and
the poses stage is skipped. Timings on a shared machine are inflated by the other processes' load: the
header prints the load average before and after, and CPU seconds (less sensitive to contention) are shown
beside wall seconds.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BIRD = DATA / "llff_bird"

PAPER = {
    "train": "15.7 min / scene (RTX 4090)",
    "view": "0.147 s / image (RTX 4090)",
    "ten": "1.47 s (10 x 0.147 s, RTX 4090)",
}
TARGET_CPU = {"train": 300.0, "ten": 2.0, "poses": 120.0}
TARGET_GPU = {"train": 60.0, "ten": 0.050}
MODES = {  # epochs actually run for the train stage, epochs per scaling run, whether SfM runs
    "quick": {"train_epochs": 5, "scale_epochs": 2, "scale_views": (25, 50, 100), "sfm": False, "reps": 2},
    "default": {"train_epochs": 20, "scale_epochs": 3, "scale_views": (25, 50, 100), "sfm": True, "reps": 3},
    "full": {"train_epochs": None, "scale_epochs": 3, "scale_views": (25, 50, 100), "sfm": True, "reps": 5},
}


# ---- helpers used inside a stage process --------------------------------------------------------


def _rss_mb() -> float:
    """Current resident set size (MB) of this process."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KB on Linux


class Clock:
    """Wall and CPU seconds of a block; on CUDA it synchronises first so queued kernels are counted."""

    def __init__(self, cuda: bool = False) -> None:
        self.cuda = cuda

    def _sync(self) -> None:
        if self.cuda:
            import torch

            torch.cuda.synchronize()

    def __enter__(self) -> "Clock":
        self._sync()
        self.t0, self.c0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc) -> None:
        self._sync()
        self.wall, self.cpu = time.perf_counter() - self.t0, time.process_time() - self.c0


def synthetic_scene(n: int, width: int = 128, height: int = 96):
    """n views of a textured plane (z = 2) from cameras on a line, looking down +z. Images in memory."""
    import numpy as np

    from sparself.capture.scene import Camera, Frame, Scene
    from sparself.core.geometry import Pose

    f, depth, step = 0.9 * width, 2.0, 0.6 / max(n - 1, 1)
    cam = Camera.pinhole(width, height, f)
    v, u = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    frames = []
    for i in range(n):
        cx = i * step
        x, y = cx + depth * (u - width / 2) / f, depth * (v - height / 2) / f
        img = np.stack(
            [
                0.5 + 0.3 * np.sin(9 * x + 2 * y),
                0.5 + 0.3 * np.cos(7 * y - 3 * x),
                0.5 + 0.2 * np.sin(5 * x) * np.cos(6 * y),
            ],
            -1,
        ).astype(np.float32)
        frames.append(
            Frame(
                f"v{i:03d}.png",
                Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([cx, 0, 0])),
                1,
                float(i),
                None,
                img,
            )
        )
    return Scene({1: cam}, frames, bounds=(1.0, 4.0), source=f"synthetic plane ({n} views)")


def bench_scene(n: int, size: int):
    """n source views at ``size`` px (long side), images decoded and resized once, held in memory:
    llff_bird evenly subsampled (every 7th frame for n = 25) if present, else synthetic."""
    import numpy as np

    if not BIRD.is_dir():
        return synthetic_scene(n, size, max(1, round(size * 0.75)))
    from sparself.capture.io import read_scene

    full = read_scene(BIRD)
    idx = list(range(0, 7 * 25, 7)) if n == 25 else [int(i) for i in np.round(np.linspace(0, len(full) - 1, n))]
    return materialised(full.subset(idx).resized(size))


def materialised(scene):
    return replace(scene, frames=[replace(f, image=scene.load(i)) for i, f in enumerate(scene.frames)])


def default_targets(scene):
    """The default plan (8 midpoints + 2 extrapolations) and the sources on its index scale."""
    from sparself.synthesis.plan import PlanConfig, plan_sequence

    return plan_sequence(scene, PlanConfig())


def _device(name: str):
    import torch

    return "cuda" if name == "cuda" or (name == "auto" and torch.cuda.is_available()) else "cpu"


def _gpu_peak_reset(cuda: bool) -> None:
    if cuda:
        import torch

        torch.cuda.reset_peak_memory_stats()


def _mem(cuda: bool, base_rss: float) -> dict:
    out = {"peak_rss_mb": _peak_mb(), "base_rss_mb": base_rss}
    if cuda:
        import torch

        out["gpu_peak_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return out


def train_config(device: str, epochs: int, extra: dict | None = None):
    """The configuration the benchmark trains: the CPU defaults at 128 px, or the paper's on GPU.
    extra: TrainConfig fields given on the command line (--amp, --compile)."""
    from sparself.synthesis.train_config import TrainConfig

    extra = extra or {}
    if device == "cuda":  # the paper's setting: 224 px input, ResNet-18 fine-tuned end to end
        return TrainConfig(epochs=epochs, size=224, backbone_size=224, device="cuda", **extra)
    return TrainConfig(epochs=epochs, size=128, device="cpu", **extra)


# ---- stages (each runs in its own process) -----------------------------------------------------------


def stage_train(p: dict) -> dict:
    import numpy as np

    from sparself.synthesis import train as tr

    dev = _device(p["device"])
    cuda = dev == "cuda"
    target_epochs = train_config(dev, 100).epochs
    epochs = p["epochs"] or target_epochs
    scene = bench_scene(25, 224 if cuda else 128)
    cfg = train_config(dev, epochs, p.get("extra"))
    ck_times = []
    save = tr._save_checkpoint

    def timed_save(*a, **k):  # wrap (not change) checkpoint writing, to extrapolate its cost
        with Clock(cuda) as c:
            save(*a, **k)
        ck_times.append(c.wall)

    tr._save_checkpoint = timed_save
    base = _rss_mb()
    _gpu_peak_reset(cuda)
    with Clock(cuda) as c:
        tr.train(scene, Path(p["run"]), cfg, progress=False, overwrite=True)
    import csv

    with open(Path(p["run"]) / tr.LOG) as f:
        rows = list(csv.DictReader(f))
    walls = [float(r["seconds"]) for r in rows]
    cpus = [float(r["cpu_seconds"]) for r in rows]
    steady = slice(1, None) if len(rows) > 2 else slice(None)  # epoch 1 warms caches and allocators
    ep_wall, ep_cpu = float(np.median(walls[steady])), float(np.median(cpus[steady]))
    setup = c.wall - sum(walls) - sum(ck_times)
    n_ck = len([e for e in range(1, target_epochs + 1) if e % cfg.checkpoint_every == 0 or e == target_epochs])
    est = setup + target_epochs * ep_wall + n_ck * float(np.mean(ck_times) if ck_times else 0.0)
    est_cpu = c.cpu - sum(cpus) + target_epochs * ep_cpu
    return {
        "epochs_run": epochs,
        "target_epochs": target_epochs,
        "total_wall": c.wall,
        "total_cpu": c.cpu,
        "epoch_wall": ep_wall,
        "epoch_cpu": ep_cpu,
        "first_epoch_wall": walls[0],
        "setup_wall": setup,
        "checkpoint_wall": float(np.mean(ck_times)) if ck_times else 0.0,
        "est_total_wall": est if epochs != target_epochs else c.wall,
        "est_total_cpu": est_cpu if epochs != target_epochs else c.cpu,
        "views": len(scene),
        "hw": list(scene.load(0).shape[:2]),
        "device": dev,
        "backbone": f"{cfg.backbone_size or (224 if cuda else 64)} px",
        "amp": cfg.amp,
        "compile": cfg.compile,
        **_mem(cuda, base),
    }


def stage_infer(p: dict) -> dict:
    import numpy as np

    from sparself.synthesis.run import load_run
    from sparself.synthesis.synthesize import synthesize

    dev = _device(p["device"])
    cuda = dev == "cuda"
    run = load_run(p["run"], device=dev)
    scene = bench_scene(25, 224 if cuda else 128)
    sources, targets = default_targets(scene)
    base = _rss_mb()
    synthesize(run, sources, targets[:2])  # warm-up (allocator, kernels)
    _gpu_peak_reset(cuda)
    per, per_cpu = [], []
    for t in targets:
        with Clock(cuda) as c:
            synthesize(run, sources, [t])
        per.append(c.wall)
        per_cpu.append(c.cpu)
    batched, batched_cpu = [], []
    for _ in range(p["reps"]):
        with Clock(cuda) as c:
            out = synthesize(run, sources, targets)
        batched.append(c.wall)
        batched_cpu.append(c.cpu)
    return {
        "views": len(targets),
        "hw": list(out.shape[1:3]),
        "per_view_wall": float(np.median(per)),
        "per_view_cpu": float(np.median(per_cpu)),
        "ten_wall": float(np.median(batched)),
        "ten_cpu": float(np.median(batched_cpu)),
        **_mem(cuda, base),
    }


def stage_poses(p: dict) -> dict:
    from sparself.capture.images import list_images
    from sparself.capture.sfm import SfmConfig, recover_poses

    folder = BIRD / "images"
    names = [q.name for q in list_images(folder)][::7][:25]
    base = _rss_mb()
    with Clock() as c:
        scene, report = recover_poses(folder, SfmConfig(max_image_size=1000), names=names)
    return {
        "images": len(names),
        "registered": report.num_registered,
        "wall": c.wall,
        "cpu": c.cpu,
        "stages": report.timings,
        "hw": list(scene.load(0).shape[:2]),
        **_mem(False, base),
    }


def stage_scale(p: dict) -> dict:
    import numpy as np

    from sparself.synthesis import train as tr
    from sparself.synthesis.plan import PlanConfig, plan_sequence
    from sparself.synthesis.synthesize import synthesize

    dev = _device(p["device"])
    cuda = dev == "cuda"
    n = p["views"]
    scene = bench_scene(n, 224 if cuda else 128)
    base = _rss_mb()
    _gpu_peak_reset(cuda)
    plans = []
    for _ in range(max(5, p["reps"])):
        with Clock() as c:
            sources, targets = plan_sequence(scene, PlanConfig())
        plans.append(c.wall)
    cfg = train_config(dev, p["epochs"], p.get("extra"))
    with tempfile.TemporaryDirectory() as d:
        run = tr.train(sources, Path(d) / "run", cfg, progress=False)
        import csv

        with open(Path(d) / "run" / tr.LOG) as f:
            rows = list(csv.DictReader(f))
    ep = rows[1:] if len(rows) > 1 else rows
    synthesize(run, sources, targets[:1])  # warm-up
    syn = []
    for _ in range(p["reps"]):
        with Clock(cuda) as c:
            synthesize(run, sources, targets)
        syn.append((c.wall, c.cpu))
    return {
        "views": n,
        "plan_wall": float(np.median(plans)),
        "epoch_wall": float(np.median([float(r["seconds"]) for r in ep])),
        "epoch_cpu": float(np.median([float(r["cpu_seconds"]) for r in ep])),
        "synth_wall": float(np.median([s[0] for s in syn])),
        "synth_cpu": float(np.median([s[1] for s in syn])),
        **_mem(cuda, base),
    }


STAGES = {"train": stage_train, "infer": stage_infer, "poses": stage_poses, "scale": stage_scale}


def _stage_main(name: str, params: str, threads: int) -> None:
    import torch

    torch.set_num_threads(threads)
    logging.basicConfig(level=logging.ERROR)
    result = STAGES[name](json.loads(params))
    print("RESULT " + json.dumps(result))


def run_stage(name: str, params: dict, threads: int, timeout: float = 1800) -> dict:
    """Run one stage in a fresh interpreter; -> its result dict, or {"error": ...}."""
    cmd = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--stage",
        name,
        "--params",
        json.dumps(params),
        "--threads",
        str(threads),
    ]
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    for line in reversed(r.stdout.splitlines()):
        if line.startswith("RESULT "):
            out = json.loads(line[7:])
            out["process_wall"] = time.perf_counter() - t0
            return out
    tail = (r.stderr or r.stdout).strip().splitlines()[-3:]
    return {"error": f"exit {r.returncode}: {' | '.join(tail)}"}


# ---- the table -------------------------------------------------------------------------------------


def _s(x: float) -> str:
    if x != x:
        return "n/a"
    return f"{x * 1000:.0f} ms" if x < 1 else f"{x:.1f} s" if x < 120 else f"{x:.0f} s ({x / 60:.1f} min)"


def _mb(r: dict) -> str:
    s = f"{r['peak_rss_mb']:.0f} MB RSS (+{r['peak_rss_mb'] - r['base_rss_mb']:.0f})"
    if "gpu_peak_mb" in r:
        s += f"; {r['gpu_peak_mb']:.0f} MB GPU"
    return s


def _ok(x: float, target: float) -> str:
    return "**met**" if x <= target else "**missed**"


def table(res: dict, env: dict) -> str:
    cuda = env["device"] == "cuda"
    tgt = TARGET_GPU if cuda else TARGET_CPU
    hw = "H100 target" if cuda else "2-core CPU target"
    lines = [
        f"sparself benchmark, mode `{env['mode']}`, {env['date']}",
        "",
        f"- machine: {env['machine']}; torch {env['torch']}; device **{env['device']}**; torch threads "
        f"{env['threads']}; amp {env['amp']}; compile {env['compile']}",
        f"- load average (1 min) before / after: {env['load_before']:.2f} / {env['load_after']:.2f} on "
        f"{env['cores']} cores"
        + (
            " — CONTENDED: other processes shared the cores, timings are inflated"
            if max(env["load_before"], env["load_after"]) > env["cores"] * 0.75
            else ""
        ),
        f"- data: {env['data']}",
        "",
        f"| stage | measure | wall | CPU | peak memory | {hw} | paper |",
        "|---|---|---|---|---|---|---|",
    ]
    t = res.get("train", {})
    if "error" in t:
        lines.append(f"| train | — | failed: {t['error']} | | | | |")
    elif t:
        extra = "" if t["epochs_run"] == t["target_epochs"] else f" (extrapolated from {t['epochs_run']} epochs run)"
        cond = f"{t['views']} views at {t['hw'][1]}x{t['hw'][0]}, backbone {t['backbone']}"
        lines.append(f"| train | per epoch ({cond}) | {_s(t['epoch_wall'])} | {_s(t['epoch_cpu'])} | {_mb(t)} | | |")
        lines.append(
            f"| train | total, {t['target_epochs']} epochs{extra} | {_s(t['est_total_wall'])} | "
            f"{_s(t['est_total_cpu'])} | {_mb(t)} | ≤ {_s(tgt['train'])}: {_ok(t['est_total_wall'], tgt['train'])} "
            f"| {PAPER['train']} |"
        )
    i = res.get("infer", {})
    if "error" in i:
        lines.append(f"| infer | — | failed: {i['error']} | | | | |")
    elif i:
        lines.append(
            f"| infer | per view, one call each ({i['hw'][1]}x{i['hw'][0]}) | {_s(i['per_view_wall'])} | "
            f"{_s(i['per_view_cpu'])} | {_mb(i)} | | {PAPER['view']} |"
        )
        lines.append(
            f"| infer | {i['views']} views, one batched call | {_s(i['ten_wall'])} | {_s(i['ten_cpu'])} | "
            f"{_mb(i)} | ≤ {_s(tgt['ten'])}: {_ok(i['ten_wall'], tgt['ten'])} | {PAPER['ten']} |"
        )
    q = res.get("poses", {})
    if "error" in q:
        lines.append(f"| poses | — | failed: {q['error']} | | | | |")
    elif q.get("skipped"):
        lines.append(f"| poses | — | skipped ({q['skipped']}) | | | | |")
    elif q:
        st = ", ".join(f"{k} {v:.1f} s" for k, v in q["stages"].items())
        lines.append(
            f"| poses | pycolmap, {q['registered']}/{q['images']} registered at {q['hw'][1]}x{q['hw'][0]} "
            f"({st}) | {_s(q['wall'])} | {_s(q['cpu'])} | {_mb(q)} | ≤ {_s(TARGET_CPU['poses'])} on 2 cores: "
            f"{_ok(q['wall'], TARGET_CPU['poses'])} | — |"
        )
    sc = res.get("scale", [])
    ok = [r for r in sc if "error" not in r]
    for r in sc:
        if "error" in r:
            lines.append(f"| scale | {r.get('views')} views | failed: {r['error']} | | | | |")
    if ok:
        b = ok[0]
        lines += [
            "",
            "Scaling with the number of source views (cost ratio against "
            f"{b['views']} views; linear growth = the view ratio; each row its own process):",
            "",
            "| views | view ratio | plan | ratio | train epoch (wall / CPU) | ratio (CPU) | "
            "synthesize 10 views (wall / CPU) | ratio (CPU) | peak memory | no worse than linear |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in ok:
            vr = r["views"] / b["views"]
            rp, re, rs = (
                r["plan_wall"] / b["plan_wall"],
                r["epoch_cpu"] / b["epoch_cpu"],
                r["synth_cpu"] / b["synth_cpu"],
            )
            lin = all(x <= vr * 1.15 for x in (re, rs))  # 15 % slack for timing noise
            lines.append(
                f"| {r['views']} | {vr:.1f} | {_s(r['plan_wall'])} | {rp:.2f} | {_s(r['epoch_wall'])} / "
                f"{_s(r['epoch_cpu'])} | {re:.2f} | {_s(r['synth_wall'])} / {_s(r['synth_cpu'])} | {rs:.2f} | "
                f"{_mb(r)} | {'yes' if lin else '**no**'} |"
            )
        lines.append("")
        lines.append(
            "The linearity check uses training and synthesis CPU time (15 % slack for noise). Planning costs "
            "milliseconds (an O(N^2) nearest-neighbour path). A training epoch holds an O(N^2 / batch) part "
            "by construction: every step runs the LSTM over the sources before its targets (up to N steps) "
            "and an epoch has N / batch steps; the decoder's linear cost dominates at these sizes."
        )
    if not cuda:
        lines += [
            "",
            "GPU figures (the paper's setting: 224 px input, 100 epochs, ResNet-18 fine-tuned; 10-view "
            "batched inference; targets ≤ 60 s training on an H100, ≤ 50 ms for 10 views) are **not measured "
            "here: this machine has no GPU**. `python benchmarks/run.py` runs them when torch sees CUDA.",
        ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_const", const="quick", dest="mode", help="smoke run, ~3 min")
    g.add_argument(
        "--full",
        action="store_const",
        const="full",
        dest="mode",
        help="run every training epoch (no extrapolation); longer than 10 min on CPU",
    )
    ap.add_argument("--out", type=Path, help="also write the markdown table to this file")
    ap.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    ap.add_argument("--threads", type=int, default=min(2, os.cpu_count() or 1), help="torch threads (default 2)")
    ap.add_argument("--stages", default="train,infer,poses,scale", help="comma-separated subset to run")
    ap.add_argument("--json", type=Path, help="also write the raw results as JSON")
    ap.add_argument(
        "--amp",
        choices=("auto", "off", "fp16", "bf16"),
        default="auto",
        help="TrainConfig.amp (auto: fp16 + gradient scaling on CUDA, float32 on CPU)",
    )
    ap.add_argument("--compile", action="store_true", help="TrainConfig.compile: torch.compile backbone and decoder")
    ap.add_argument("--stage", help=argparse.SUPPRESS)
    ap.add_argument("--params", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.stage:
        _stage_main(args.stage, args.params, args.threads)
        return 0
    mode = args.mode or "default"
    m = MODES[mode]
    import torch

    dev = "cuda" if args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available()) else "cpu"
    stages = [s.strip() for s in args.stages.split(",") if s.strip()]
    env = {
        "mode": mode,
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "torch": torch.__version__,
        "device": dev,
        "threads": args.threads,
        "amp": args.amp,
        "compile": args.compile,
        "cores": os.cpu_count(),
        "load_before": os.getloadavg()[0],
        "machine": (torch.cuda.get_device_name(0) if dev == "cuda" else platform.processor() or platform.machine()),
        "data": (
            f"{BIRD} (25 views = every 7th frame)"
            if BIRD.is_dir()
            else "synthetic textured plane (../shared/data/llff_bird not found)"
        ),
    }
    res: dict = {}
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        run = str(Path(d) / "run")
        extra = {k: v for k, v in (("amp", args.amp), ("compile", args.compile)) if v not in ("auto", False)}
        common = {"device": dev, "reps": m["reps"], "extra": extra}
        if "train" in stages or "infer" in stages:
            print(
                f"[bench] train ({'all' if m['train_epochs'] is None else m['train_epochs']} epochs) ...",
                file=sys.stderr,
                flush=True,
            )
            res["train"] = run_stage("train", {**common, "run": run, "epochs": m["train_epochs"]}, args.threads)
        if "infer" in stages and "error" not in res.get("train", {}):
            print("[bench] infer ...", file=sys.stderr, flush=True)
            res["infer"] = run_stage("infer", {**common, "run": run}, args.threads)
        if "train" not in stages:
            res.pop("train", None)
    if "poses" in stages:
        if not m["sfm"]:
            res["poses"] = {"skipped": "--quick"}
        elif not BIRD.is_dir():
            res["poses"] = {"skipped": f"{BIRD} not found"}
        else:
            print("[bench] poses (pycolmap) ...", file=sys.stderr, flush=True)
            res["poses"] = run_stage("poses", common, args.threads)
    if "scale" in stages:
        res["scale"] = []
        for n in m["scale_views"]:
            print(f"[bench] scale: {n} views ...", file=sys.stderr, flush=True)
            r = run_stage("scale", {**common, "views": n, "epochs": m["scale_epochs"]}, args.threads)
            r.setdefault("views", n)
            res["scale"].append(r)
    env["load_after"] = os.getloadavg()[0]
    text = table(res, env) + f"\n(benchmark wall time {time.perf_counter() - t_start:.0f} s)\n"
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    if args.json:
        args.json.write_text(json.dumps({"env": env, "results": res}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
