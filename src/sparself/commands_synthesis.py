"""The network's commands: train, synthesize, densify, and batch (densify or evaluate over many captures)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from sparself.commands import (
    EVAL_OWNS,
    add_common_options,
    eval_options,
    export_options,
    kept_work_hint,
    plan_config,
    plan_options,
    resume_command,
    took,
    train_config,
    train_options,
    views_summary,
)


def add_train(sub) -> None:
    p = sub.add_parser(
        "train",
        help="train the CNN–LSTM view synthesizer on a posed scene",
        description="Per-scene training without leakage: each training frame is predicted from the others, "
        "its own step in the sequence being a query (pose + index, no image). Writes RUN/"
        "checkpoint.pt (every few epochs), RUN/config.json and RUN/train_log.csv.",
    )
    p.add_argument("scene", type=Path, help="scene folder or pose file (COLMAP, LLFF, transforms.json, Middlebury)")
    p.add_argument("--out", type=Path, required=True, help="run folder to write")
    train_options(p)
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    add_common_options(p)
    p.set_defaults(func=run_train)


def run_train(args) -> int:
    from sparself.synthesis.train import train_scene

    t0 = time.perf_counter()
    try:
        run = train_scene(args.scene, args.out, train_config(args), resume=args.resume, overwrite=args.overwrite)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(resume_hint(args)) from None
    e = run.cfg.epochs
    print(
        f"trained {e} epoch{'s' if e != 1 else ''} on {len(run.meta.sources)} real views -> {args.out} "
        f"(checkpoint.pt, config.json, train_log.csv) in {took(t0)}"
    )
    return 0


def resume_hint(args) -> str:
    """After Ctrl-C in `train`: which checkpoint is kept and the exact command that continues from it."""
    from sparself.synthesis.run import CHECKPOINT, CONFIG
    from sparself.synthesis.train import checkpoint_epoch

    again = resume_command(args)
    epoch = checkpoint_epoch(args.out)
    if epoch is not None:
        return f"the checkpoint at epoch {epoch} is kept in {args.out / CHECKPOINT}; continue with: {again}"
    if (args.out / CONFIG).is_file():
        return f"stopped before the first checkpoint; start again with: {again}"
    return "nothing was written; run the command again"


def add_synthesize(sub) -> None:
    p = sub.add_parser(
        "synthesize",
        help="synthesize the views of a plan with a trained run and write the dense scene",
        description="Synthesizes the planned poses from the run's scene (minus its holdout frames) and writes "
        "originals + new views as images/ + sparse/0/ (COLMAP) + poses_bounds.npy (LLFF) + "
        "transforms.json (nerfstudio).",
    )
    p.add_argument("run", type=Path, help="run folder written by `sparself train`")
    p.add_argument("--plan", type=Path, required=True, help="plan JSON written by `sparself plan`")
    p.add_argument("--out", type=Path, required=True, help="folder for the densified scene")
    p.add_argument(
        "--scene",
        type=Path,
        default=None,
        help="source scene (default: the one the run used, else the dense scene densify wrote beside the run); "
        "a dense scene sparself wrote gives its photos under their own names, never its synthesized views",
    )
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    export_options(p)
    add_common_options(p)
    p.set_defaults(func=run_synthesize)


def run_synthesize(args) -> int:
    from sparself.synthesis.synthesize import synthesize_plan

    t0 = time.perf_counter()
    dense = synthesize_plan(
        args.run,
        args.plan,
        args.out,
        scene_path=args.scene,
        overwrite=args.overwrite,
        downscaled=args.downscaled,
        triangulate=args.triangulate,
    )
    written = "images/, sparse/0, poses_bounds.npy, transforms.json"
    print(f"wrote {views_summary(dense)} -> {args.out} ({written}) in {took(t0)}")
    return 0


def add_densify(sub) -> None:
    p = sub.add_parser(
        "densify",
        help="photos -> poses -> plan -> train -> synthesize -> dense scene, in one command",
        description="PHOTOS is a folder of photos (posed with COLMAP) or anything `sparself info` reads. "
        "Writes OUT/scene (images/, sparse/0/, poses_bounds.npy, transforms.json) and OUT/run.",
    )
    p.add_argument("photos", type=Path, help="folder of photos, or a posed scene")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    densify_options(p)
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue a run that was stopped (Ctrl-C, kill, an error) from the steps it finished: its poses, "
        "its network's last checkpoint and its self-check's fits, kept in .OUT.sparself-work beside --out "
        "(the same result as a run never stopped; a changed option does the steps it changes again)",
    )
    export_options(p)
    add_common_options(p)
    p.set_defaults(func=run_densify)


def positive(text: str) -> int:
    """A whole number above 0 (argparse reports anything else in one line, before any work)."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n <= 0:
        raise argparse.ArgumentTypeError(f"expected a whole number of pixels above 0, got {text!r}")
    return n


def densify_options(p: argparse.ArgumentParser) -> None:
    """The plan, the test split, the output size and the training options: shared by `densify` and
    `batch densify`."""
    from sparself.core.options import add_options
    from sparself.pipeline import DensifyConfig

    plan_options(p)
    add_options(p, DensifyConfig, skip=tuple(n for n in DensifyConfig.__dataclass_fields__ if n != "test_split"))
    p.add_argument(
        "--out-size",
        type=positive,
        default=None,
        help="long side in px of the written scene and of training (default: as read)",
    )
    train_options(p, skip=("size",))
    from sparself.core.options import add_options
    from sparself.evaluation.selfcheck import SelfCheckConfig

    add_options(p, SelfCheckConfig)


def densify_config(args, **kw):
    from sparself.core.options import from_args
    from sparself.evaluation.selfcheck import SelfCheckConfig
    from sparself.pipeline import DensifyConfig

    return DensifyConfig(
        train=train_config(args),
        plan=plan_config(args),
        check=from_args(SelfCheckConfig, args),
        out_size=args.out_size,
        downscaled=args.downscaled,
        triangulate=args.triangulate,
        test_split=args.test_split,
        **kw,
    )


def run_densify(args) -> int:
    from sparself.pipeline import densify

    t0 = time.perf_counter()
    try:
        dense = densify(args.photos, args.out, densify_config(args, overwrite=args.overwrite), resume=args.resume)
    except KeyboardInterrupt:  # its output appears whole or not at all; its finished steps may be kept
        raise KeyboardInterrupt(kept_work_hint(args)) from None
    print(
        f"wrote {views_summary(dense)} -> {args.out / 'scene'} (run: {args.out / 'run'}, plan: "
        f"{args.out / 'plan.json'}) in {took(t0)}"
    )
    return 0


def batch_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "manifest",
        type=Path,
        help="captures to run: a text file of paths (one a line), or JSON/YAML with per-capture options",
    )
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        help="batch folder: captures/<name>/ per capture, logs/, report.md/html, results.json; run again to resume",
    )
    g = p.add_argument_group("where the units run")
    g.add_argument(
        "--address",
        default=None,
        help="join a Ray cluster: auto (started with `ray start --head`) or ray://host:port; default: "
        "start Ray inside this command on this machine's CPUs",
    )
    g.add_argument("--local", action="store_true", help="no Ray: run the units one after another in this process")
    g.add_argument(
        "--workers", type=int, default=None, help="units at a time (default: as many as the CPUs/GPUs allow)"
    )
    g.add_argument("--cpus-per-task", type=int, default=1, help="CPU threads per unit (default 1)")
    g.add_argument(
        "--gpus-per-task",
        type=float,
        default=None,
        help="GPUs per unit (default: 1 when the cluster has GPUs and --device is not cpu, else 0)",
    )


def add_batch(sub) -> None:
    p = sub.add_parser(
        "batch",
        help="densify or evaluate many captures in parallel (Ray), resumable, with one report",
        description="Run `densify` (one unit per capture) or `evaluate` (one unit per capture and seed) over "
        "the captures of a manifest as Ray tasks: on this machine's cores by default, on a cluster "
        "with --address. A unit finished by an earlier run is skipped; a failing capture is "
        "reported and the others go on. Needs Ray: pip install 'sparself[ray]' (or use --local).",
    )
    kinds = p.add_subparsers(dest="kind", metavar="KIND", required=True)
    d = kinds.add_parser(
        "densify",
        help="`sparself densify` on every capture of the manifest",
        description="Each capture is densified into OUT/captures/<name>/ as by `sparself densify`.",
    )
    batch_options(d)
    densify_options(d)
    export_options(d)
    add_common_options(d)
    d.set_defaults(func=run_batch)
    e = kinds.add_parser(
        "evaluate",
        help="`sparself evaluate` on every capture and seed of the manifest",
        description="Each capture x seed k is evaluated into OUT/captures/<name>/seed<k>/ as by "
        "`sparself evaluate --seeds 1 --first-seed k`; OUT/report.md combines them "
        "(mean ± std over seeds and over captures).",
    )
    batch_options(e)
    eval_options(e)
    add_common_options(e)
    e.set_defaults(func=run_batch)


def run_batch(args) -> int:
    from sparself.batch import run_batch
    from sparself.batch_units import BatchConfig

    if args.kind == "densify":
        base = densify_config(args)
    else:
        from sparself.core.options import given
        from sparself.evaluation.config import EvalConfig, eval_config

        base = eval_config(quick=args.quick, train_cfg=train_config(args, skip=EVAL_OWNS), **given(EvalConfig, args))
    cfg = BatchConfig(
        address=args.address,
        local=args.local,
        workers=args.workers,
        cpus_per_task=args.cpus_per_task,
        gpus_per_task=args.gpus_per_task,
        progress=False if args.quiet else None,
    )
    res = run_batch(args.kind, args.manifest, args.out, base, cfg)
    done = [u for u in res.units if u.status == "ok"]
    print(
        f"batch {args.kind}: {len(done)} of {len(res.units)} unit(s) done "
        f"({sum(u.skipped for u in done)} by an earlier run), {len(res.failed)} failed -> {args.out / 'report.md'}"
    )
    for u in res.failed:
        print(f"  failed: {u.label(args.kind)}: {u.error}", file=sys.stderr)
    return 1 if res.failed else 0
