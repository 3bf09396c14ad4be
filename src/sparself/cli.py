"""Command-line interface: argument parsing only. Each command calls one library function.

To add a command: write ``_add_<name>(sub)`` that builds its parser and sets ``func`` to a
``_run_<name>(args)`` that calls the library, then list it in ``_COMMANDS``.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
import time
from pathlib import Path

from sparself import __version__
from sparself.core.errors import SparselfError
from sparself.core.interrupts import signals_interrupt, stopped_by
from sparself.core.locks import output_lock
from sparself.core.logs import BarSafeHandler, Repeats
from sparself.core.space import os_error_line

log = logging.getLogger("sparself")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--debug", action="store_true", help="show full tracebacks and debug logging")
    p.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")


_COMMANDS: list = []  # filled below: functions (subparsers) -> None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sparself",
        description=(
            "Densify a sparse photo capture (about 25 images) with synthesized views at new camera poses, "
            "so that 3D reconstruction (LLFF/MPI, NeRF, Gaussian splatting) built on it looks better. "
            "Typical use: `sparself densify PHOTOS --out DIR`."
        ),
    )
    parser.add_argument("--version", action="version", version=f"sparself {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in _COMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # for the exact --resume command after Ctrl-C
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    level = logging.DEBUG if args.debug else (logging.WARNING if args.quiet else logging.INFO)
    # a handler on our own logger, removed afterwards, so that main() can be called in-process (tests)
    handler = BarSafeHandler()
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    repeats = Repeats()
    handler.addFilter(repeats)
    pkg = logging.getLogger("sparself")
    old_level, old_propagate = pkg.level, pkg.propagate
    pkg.addHandler(handler)
    pkg.setLevel(level)
    pkg.propagate = False
    try:
        # one writer per output for the whole command: a second one into the same --out is refused
        with signals_interrupt(), output_lock(getattr(args, "out", None)):
            return int(args.func(args) or 0)
    except SparselfError as e:
        if args.debug:
            raise
        print(f"sparself {args.command}: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM or SIGHUP: exit status 128 + the signal
        signum = stopped_by()
        by = f" by {signal.Signals(signum).name}" if signum != signal.SIGINT else ""
        print(f"sparself {args.command}: interrupted{by}" + (f"; {e}" if str(e) else ""), file=sys.stderr)
        return 128 + int(signum)
    except BrokenPipeError:  # `sparself info SCENE | head`: the reader has gone, which is no error of ours
        _drop_stdout()
        return 141  # 128 + SIGPIPE, what a shell reports for a command cut off by its pipe
    except OSError as e:  # a full disk, a path part over 255 bytes: one line; anything else is a bug
        line = os_error_line(e, getattr(args, "out", None))
        if line is None or args.debug:
            raise
        print(f"sparself {args.command}: error: {line}", file=sys.stderr)
        return 2
    finally:
        for rec in repeats.rest():
            handler.handle(rec)
        pkg.removeHandler(handler)
        pkg.setLevel(old_level)
        pkg.propagate = old_propagate


def _drop_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's final flush does not fail on the closed pipe again."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())


# ---- commands ------------------------------------------------------------------------------------


def _took(t0: float) -> str:
    """Wall time since ``t0`` for a command's summary line: '3.2 s', '4 min 05 s'."""
    s = time.perf_counter() - t0
    return f"{s:.1f} s" if s < 120 else f"{int(s // 60)} min {int(s % 60):02d} s"


def _views(scene) -> str:
    """'6 views (4 real + 2 synthesized)' of a scene whose frames say which are synthetic."""
    syn = sum(1 for f in scene.frames if f.synthetic)
    return f"{len(scene)} views ({len(scene) - syn} real + {syn} synthesized)"


# (each helper appends its _add_* function here and to _COMMANDS)


def _add_info(sub) -> None:
    p = sub.add_parser(
        "info",
        help="describe a scene: views, image size, cameras, field of view, pose bounds",
        description="Print what a scene holds: number of views, image size, camera model and intrinsics, "
        "field of view, camera-centre extent, depth bounds and scene scale. SCENE is a COLMAP "
        "model folder, an LLFF folder (poses_bounds.npy), a transforms.json or a Middlebury set.",
    )
    p.add_argument("scene", type=Path, help="scene folder or pose file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    _common(p)
    p.set_defaults(func=_run_info)


def _run_info(args) -> int:
    from sparself.capture.info import describe

    print(describe(args.scene, as_json=args.json))
    return 0


_COMMANDS.append(_add_info)


def _plan_options(p: argparse.ArgumentParser) -> None:
    """The novel-pose plan's options (built from PlanConfig), shared by `plan` and `densify`."""
    from sparself.core.options import add_options
    from sparself.synthesis.plan import PlanConfig

    add_options(p, PlanConfig)


def _plan_config(args):
    from sparself.core.options import from_args
    from sparself.synthesis.plan import PlanConfig

    return from_args(PlanConfig, args)


def _add_plan(sub) -> None:
    p = sub.add_parser(
        "plan",
        help="plan novel camera poses (midpoints + extrapolations) for a scene",
        description="The paper's novel-pose plan: camera centres are LERPed and rotations SLERPed on the "
        "shortest arc, at t=0.5 between consecutive views and t=1.2 past both ends of the path "
        "(8 + 2 = 10 poses by default). Writes a JSON plan; --plot draws the cameras.",
    )
    p.add_argument("scene", type=Path, help="scene folder or pose file")
    p.add_argument("--out", type=Path, required=True, help="plan file to write (JSON)")
    _plan_options(p)
    p.add_argument("--plot", type=Path, default=None, help="also draw the cameras to this PNG")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    _common(p)
    p.set_defaults(func=_run_plan)


def _run_plan(args) -> int:
    from sparself.synthesis.plan import make_plan

    t0 = time.perf_counter()
    frames = make_plan(args.scene, args.out, _plan_config(args), plot=args.plot, overwrite=args.overwrite)
    print(
        f"planned {len(frames)} novel poses -> {args.out}"
        + (f" (plot: {args.plot})" if args.plot else "")
        + f" in {_took(t0)}"
    )
    return 0


_COMMANDS.append(_add_plan)


def _add_evaluate(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="held-out evaluation: view synthesis and N vs N+synthesized reconstruction, with a report",
        description="Run the honest evaluation protocol on one or many captures: hold out every 8th interior "
        "frame (never seen by any step), take N evenly spaced inputs from dense captures, score "
        "sparself and the baselines (nearest, blend, flow, plane sweep) at the held-out poses, and "
        "reconstruct (MPI, NeRF, 3DGS) from N real views vs N + synthesized views (plus the "
        "real-photo oracle). Writes results.json, report.md, report.html and PNG figures to --out.",
    )
    p.add_argument("scenes", type=Path, nargs="*", help="scene folders or pose files")
    p.add_argument("--out", type=Path, required=True, help="output folder (written atomically)")
    p.add_argument("--manifest", type=Path, default=None, help="file listing scene paths, one per line")
    _eval_options(p)
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    _common(p)
    p.set_defaults(func=_run_evaluate)


_EVAL_OWNS = ("size", "epochs", "seed", "holdout")  # training options the evaluation sets itself


def _quick() -> dict:
    from sparself.evaluation.config import QUICK

    return QUICK


def _eval_options(p: argparse.ArgumentParser) -> None:
    """--quick, EvalConfig's fields, then the network's training options (both built from their dataclasses)."""
    from sparself.core.options import add_options
    from sparself.evaluation.config import EvalConfig

    p.add_argument(
        "--quick",
        action="store_true",
        help="minutes instead of hours on a CPU: 64 px, 1 seed, 3 network epochs, short NeRF, at most 6 "
        "scored frames, one baseline densified",
    )
    add_options(p, EvalConfig, unset=True, notes={k: f"; --quick: {v}" for k, v in _quick().items()})
    g = p.add_argument_group("network training (as `sparself train`; seed, size and epochs are set above)")
    _train_options(g, skip=_EVAL_OWNS)


def _run_evaluate(args) -> int:
    from sparself.core.options import given
    from sparself.evaluation.config import EvalConfig
    from sparself.evaluation.evaluate import run_cli

    t0 = time.perf_counter()
    res = run_cli(
        args.scenes,
        args.out,
        args.manifest,
        quick=args.quick,
        overwrite=args.overwrite,
        train_cfg=_train_config(args, skip=_EVAL_OWNS),
        **given(EvalConfig, args),
    )
    bad = [s["name"] for s in res["scenes"] if s.get("status") != "ok"]
    print(
        f"evaluated {len(res['scenes']) - len(bad)} scene(s) -> {args.out / 'report.md'}"
        + (f"; failed: {', '.join(bad)}" if bad else "")
        + f" in {_took(t0)}"
    )
    return 1 if bad and len(bad) == len(res["scenes"]) else 0


_COMMANDS.append(_add_evaluate)


def _add_poses(sub) -> None:
    p = sub.add_parser(
        "poses",
        help="recover camera poses and intrinsics from photos (COLMAP via pycolmap)",
        description="Structure from motion on a folder of photos with pycolmap: SIFT features, exhaustive "
        "(or sequential) matching, incremental mapping, with defaults tuned for sparse captures "
        "(~25 views). Writes DIR with images/ (copies of the registered photos), sparse/0/ "
        "(COLMAP binary), poses_bounds.npy (LLFF), transforms.json (nerfstudio) and "
        "sfm_report.json. Prints how many images were registered and names the others; fails "
        "if fewer than 3 are registered.",
    )
    p.add_argument("photos", type=Path, help="folder of photos (one capture, one image size)")
    p.add_argument("--out", type=Path, required=True, help="output scene folder")
    p.add_argument(
        "--matcher",
        choices=["exhaustive", "sequential"],
        default="exhaustive",
        help="exhaustive: all pairs (default; best for ~25 views); sequential: neighbours by file "
        "name (long video-like captures)",
    )
    p.add_argument(
        "--max-image-size",
        type=int,
        default=1600,
        help="downscale the longest side to N px for feature extraction (faster; default 1600); 0 = full size",
    )
    cam = p.add_mutually_exclusive_group()
    cam.add_argument(
        "--single-camera",
        dest="single_camera",
        action="store_true",
        default=True,
        help="one shared camera for all photos (default)",
    )
    cam.add_argument(
        "--per-image-camera",
        dest="single_camera",
        action="store_false",
        help="separate intrinsics per photo (mixed zoom / devices)",
    )
    p.add_argument(
        "--link-images", action="store_true", help="symlink the photos into DIR/images instead of copying them"
    )
    p.add_argument("--overwrite", action="store_true", help="replace DIR if it exists")
    p.add_argument("--seed", type=int, default=0, help="random seed of COLMAP's RANSAC and mapper (default 0)")
    _common(p)
    p.set_defaults(func=_run_poses)


def _run_poses(args) -> int:
    from sparself.capture.sfm import SfmConfig, poses_to_folder

    t0 = time.perf_counter()
    rep = poses_to_folder(
        args.photos,
        args.out,
        SfmConfig(
            matcher=args.matcher,
            max_image_size=args.max_image_size,
            single_camera=args.single_camera,
            seed=args.seed,
            debug=args.debug,
        ),
        overwrite=args.overwrite,
        images="link" if args.link_images else "copy",
    )
    print(f"{rep.summary()} -> {args.out} in {_took(t0)}")
    return 0


_COMMANDS.append(_add_poses)


# ---- train / synthesize / densify (the CNN–LSTM synthesizer) ----------------------------------------


def _train_options(p: argparse._ActionsContainer, skip: tuple[str, ...] = ()) -> None:
    """Every TrainConfig field as an option (built from the dataclass: its defaults and help)."""
    from sparself.core.options import add_options
    from sparself.synthesis.train_config import TrainConfig

    add_options(p, TrainConfig, skip)


def _train_config(args, skip: tuple[str, ...] = ()):
    from sparself.core.options import from_args
    from sparself.synthesis.train_config import TrainConfig

    return from_args(TrainConfig, args, skip)


def _export_options(p: argparse.ArgumentParser) -> None:
    """How the dense scene is written (DensifyConfig's export fields), shared by `synthesize` and `densify`."""
    import dataclasses

    from sparself.core.options import add_options
    from sparself.pipeline import DensifyConfig

    export = ("downscaled", "triangulate")
    add_options(p, DensifyConfig, skip=tuple(f.name for f in dataclasses.fields(DensifyConfig) if f.name not in export))


def _add_train(sub) -> None:
    p = sub.add_parser(
        "train",
        help="train the CNN–LSTM view synthesizer on a posed scene",
        description="Per-scene training without leakage: each training frame is predicted from the others, "
        "its own step in the sequence being a query (pose + index, no image). Writes RUN/"
        "checkpoint.pt (every few epochs), RUN/config.json and RUN/train_log.csv.",
    )
    p.add_argument("scene", type=Path, help="scene folder or pose file (COLMAP, LLFF, transforms.json, Middlebury)")
    p.add_argument("--out", type=Path, required=True, help="run folder to write")
    _train_options(p)
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    _common(p)
    p.set_defaults(func=_run_train)


def _run_train(args) -> int:
    from sparself.synthesis.train import train_scene

    t0 = time.perf_counter()
    try:
        run = train_scene(args.scene, args.out, _train_config(args), resume=args.resume, overwrite=args.overwrite)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(_resume_hint(args)) from None
    e = run.cfg.epochs
    print(
        f"trained {e} epoch{'s' if e != 1 else ''} on {len(run.meta.sources)} real views -> {args.out} "
        f"(checkpoint.pt, config.json, train_log.csv) in {_took(t0)}"
    )
    return 0


def _resume_hint(args) -> str:
    """After Ctrl-C in `train`: which checkpoint is kept and the exact command that continues from it."""
    import shlex

    from sparself.synthesis.run import CHECKPOINT, CONFIG
    from sparself.synthesis.train import checkpoint_epoch

    argv = [a for a in args.argv if a != "--overwrite"]
    again = "sparself " + shlex.join(argv + ([] if "--resume" in argv else ["--resume"]))
    epoch = checkpoint_epoch(args.out)
    if epoch is not None:
        return f"the checkpoint at epoch {epoch} is kept in {args.out / CHECKPOINT}; continue with: {again}"
    if (args.out / CONFIG).is_file():
        return f"stopped before the first checkpoint; start again with: {again}"
    return "nothing was written; run the command again"


_COMMANDS.append(_add_train)


def _add_synthesize(sub) -> None:
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
    p.add_argument("--scene", type=Path, default=None, help="source scene (default: the one the run used)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    _export_options(p)
    _common(p)
    p.set_defaults(func=_run_synthesize)


def _run_synthesize(args) -> int:
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
    print(f"wrote {_views(dense)} -> {args.out} (images/, sparse/0, poses_bounds.npy, transforms.json) in {_took(t0)}")
    return 0


_COMMANDS.append(_add_synthesize)


def _add_densify(sub) -> None:
    p = sub.add_parser(
        "densify",
        help="photos -> poses -> plan -> train -> synthesize -> dense scene, in one command",
        description="PHOTOS is a folder of photos (posed with COLMAP) or anything `sparself info` reads. "
        "Writes OUT/scene (images/, sparse/0/, poses_bounds.npy, transforms.json) and OUT/run.",
    )
    p.add_argument("photos", type=Path, help="folder of photos, or a posed scene")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    _densify_options(p)
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    _export_options(p)
    _common(p)
    p.set_defaults(func=_run_densify)


def _positive(text: str) -> int:
    """A whole number above 0 (argparse reports anything else in one line, before any work)."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n <= 0:
        raise argparse.ArgumentTypeError(f"expected a whole number of pixels above 0, got {text!r}")
    return n


def _densify_options(p: argparse.ArgumentParser) -> None:
    """The plan, the test split, the output size and the training options: shared by `densify` and
    `batch densify`."""
    from sparself.core.options import add_options
    from sparself.pipeline import DensifyConfig

    _plan_options(p)
    add_options(p, DensifyConfig, skip=tuple(n for n in DensifyConfig.__dataclass_fields__ if n != "test_split"))
    p.add_argument(
        "--out-size",
        type=_positive,
        default=None,
        help="long side in px of the written scene and of training (default: as read)",
    )
    _train_options(p, skip=("size",))
    from sparself.core.options import add_options
    from sparself.evaluation.selfcheck import SelfCheckConfig

    add_options(p, SelfCheckConfig)


def _densify_config(args, **kw):
    from sparself.core.options import from_args
    from sparself.evaluation.selfcheck import SelfCheckConfig
    from sparself.pipeline import DensifyConfig

    return DensifyConfig(
        train=_train_config(args),
        plan=_plan_config(args),
        check=from_args(SelfCheckConfig, args),
        out_size=args.out_size,
        downscaled=args.downscaled,
        triangulate=args.triangulate,
        test_split=args.test_split,
        **kw,
    )


def _run_densify(args) -> int:
    from sparself.pipeline import densify

    t0 = time.perf_counter()
    try:
        dense = densify(args.photos, args.out, _densify_config(args, overwrite=args.overwrite))
    except KeyboardInterrupt:  # its output appears whole or not at all
        raise KeyboardInterrupt(f"nothing was written to {args.out}; run the command again") from None
    print(
        f"wrote {_views(dense)} -> {args.out / 'scene'} (run: {args.out / 'run'}, plan: "
        f"{args.out / 'plan.json'}) in {_took(t0)}"
    )
    return 0


_COMMANDS.append(_add_densify)


# ---- batch: many captures as Ray tasks --------------------------------------------------------------


def _batch_options(p: argparse.ArgumentParser) -> None:
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


def _add_batch(sub) -> None:
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
    _batch_options(d)
    _densify_options(d)
    _export_options(d)
    _common(d)
    d.set_defaults(func=_run_batch)
    e = kinds.add_parser(
        "evaluate",
        help="`sparself evaluate` on every capture and seed of the manifest",
        description="Each capture x seed k is evaluated into OUT/captures/<name>/seed<k>/ as by "
        "`sparself evaluate --seeds 1 --first-seed k`; OUT/report.md combines them "
        "(mean ± std over seeds and over captures).",
    )
    _batch_options(e)
    _eval_options(e)
    _common(e)
    e.set_defaults(func=_run_batch)


def _run_batch(args) -> int:
    from sparself.batch import run_batch
    from sparself.batch_units import BatchConfig

    if args.kind == "densify":
        base = _densify_config(args)
    else:
        from sparself.core.options import given
        from sparself.evaluation.config import EvalConfig, eval_config

        base = eval_config(quick=args.quick, train_cfg=_train_config(args, skip=_EVAL_OWNS), **given(EvalConfig, args))
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


_COMMANDS.append(_add_batch)


if __name__ == "__main__":
    sys.exit(main())
