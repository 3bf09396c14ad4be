"""The commands that read and describe captures and measure: info, plan, evaluate, poses; and the option
groups the network's commands share."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def add_common_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--debug", action="store_true", help="show full tracebacks and debug logging")
    p.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")


def took(t0: float) -> str:
    """Wall time since ``t0`` for a command's summary line: '3.2 s', '4 min 05 s'."""
    s = time.perf_counter() - t0
    return f"{s:.1f} s" if s < 120 else f"{int(s // 60)} min {int(s % 60):02d} s"


def views_summary(scene) -> str:
    """'6 views (4 real + 2 synthesized)' of a scene whose frames say which are synthetic."""
    syn = sum(1 for f in scene.frames if f.synthetic)
    return f"{len(scene)} views ({len(scene) - syn} real + {syn} synthesized)"


def add_info(sub) -> None:
    p = sub.add_parser(
        "info",
        help="describe a scene: views, image size, cameras, field of view, pose bounds",
        description="Print what a scene holds: number of views, image size, camera model and intrinsics, "
        "field of view, camera-centre extent, depth bounds and scene scale. SCENE is a COLMAP "
        "model folder, an LLFF folder (poses_bounds.npy), a transforms.json or a Middlebury set.",
    )
    p.add_argument("scene", type=Path, help="scene folder or pose file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_common_options(p)
    p.set_defaults(func=run_info)


def run_info(args) -> int:
    from sparself.capture.info import describe

    print(describe(args.scene, as_json=args.json))
    return 0


def plan_options(p: argparse.ArgumentParser) -> None:
    """The novel-pose plan's options (built from PlanConfig), shared by `plan` and `densify`."""
    from sparself.core.options import add_options
    from sparself.synthesis.plan import PlanConfig

    add_options(p, PlanConfig)


def plan_config(args):
    from sparself.core.options import from_args
    from sparself.synthesis.plan import PlanConfig

    return from_args(PlanConfig, args)


def add_plan(sub) -> None:
    p = sub.add_parser(
        "plan",
        help="plan novel camera poses (midpoints + extrapolations) for a scene",
        description="The paper's novel-pose plan: camera centres are LERPed and rotations SLERPed on the "
        "shortest arc, at t=0.5 between consecutive views and t=1.2 past both ends of the path "
        "(8 + 2 = 10 poses by default). Writes a JSON plan; --plot draws the cameras.",
    )
    p.add_argument("scene", type=Path, help="scene folder or pose file")
    p.add_argument("--out", type=Path, required=True, help="plan file to write (JSON)")
    plan_options(p)
    p.add_argument("--plot", type=Path, default=None, help="also draw the cameras to this PNG")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    add_common_options(p)
    p.set_defaults(func=run_plan)


def run_plan(args) -> int:
    from sparself.synthesis.plan import make_plan

    t0 = time.perf_counter()
    frames = make_plan(args.scene, args.out, plan_config(args), plot=args.plot, overwrite=args.overwrite)
    print(
        f"planned {len(frames)} novel poses -> {args.out}"
        + (f" (plot: {args.plot})" if args.plot else "")
        + f" in {took(t0)}"
    )
    return 0


def add_evaluate(sub) -> None:
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
    eval_options(p)
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue an evaluation that was stopped (Ctrl-C, kill, an error) from its networks' checkpoints and "
        "its finished fits, kept in .OUT.sparself-work beside --out (the same results as a run never stopped)",
    )
    add_common_options(p)
    p.set_defaults(func=run_evaluate)


EVAL_OWNS = ("size", "epochs", "seed", "holdout")  # training options the evaluation sets itself


def quick_settings() -> dict:
    from sparself.evaluation.config import QUICK

    return QUICK


def eval_options(p: argparse.ArgumentParser) -> None:
    """--quick, EvalConfig's fields, then the network's training options (both built from their dataclasses)."""
    from sparself.core.options import add_options
    from sparself.evaluation.config import EvalConfig

    p.add_argument(
        "--quick",
        action="store_true",
        help="minutes instead of hours on a CPU: 64 px, 1 seed, 30 network epochs, short NeRF, at most 6 "
        "scored frames, one baseline densified",
    )
    add_options(p, EvalConfig, unset=True, notes={k: f"; --quick: {v}" for k, v in quick_settings().items()})
    g = p.add_argument_group("network training (as `sparself train`; seed, size and epochs are set above)")
    train_options(g, skip=EVAL_OWNS)


def kept_work_hint(args) -> str:
    """After Ctrl-C in `densify` or `evaluate`: nothing written, and either where the finished steps are kept with
    the exact command that continues from them, or that the command must be run again."""
    from sparself.core.outputs import work_path

    work = work_path(args.out)
    if not work.is_dir():
        return f"nothing was written to {args.out}; run the command again"
    return (
        f"nothing was written to {args.out}; the finished steps are kept in {work}; continue with: "
        f"{resume_command(args)}"
    )


def resume_command(args) -> str:
    """The command as typed, with ``--resume`` and without ``--overwrite`` (which would start again)."""
    import shlex

    argv = [a for a in args.argv if a != "--overwrite"]
    return "sparself " + shlex.join(argv + ([] if "--resume" in argv else ["--resume"]))


def run_evaluate(args) -> int:
    from sparself.core.options import given
    from sparself.evaluation.config import EvalConfig
    from sparself.evaluation.evaluate import run_cli

    t0 = time.perf_counter()
    try:
        res = run_cli(
            args.scenes,
            args.out,
            args.manifest,
            quick=args.quick,
            overwrite=args.overwrite,
            resume=args.resume,
            train_cfg=train_config(args, skip=EVAL_OWNS),
            **given(EvalConfig, args),
        )
    except KeyboardInterrupt:  # its output appears whole or not at all; its finished steps may be kept
        raise KeyboardInterrupt(kept_work_hint(args)) from None
    bad = [s.name for s in res.failed]
    print(
        f"evaluated {len(res.scenes) - len(bad)} scene(s) -> {args.out / 'report.md'}"
        + (f"; failed: {', '.join(bad)}" if bad else "")
        + f" in {took(t0)}"
    )
    return 1 if bad and len(bad) == len(res.scenes) else 0


def add_poses(sub) -> None:
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
        help="exhaustive: all pairs (default; best for ~25 views); sequential: each photo with its next "
        "ones in capture order, IMG_2 before IMG_10 (long video-like captures)",
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
    add_common_options(p)
    p.set_defaults(func=run_poses)


def run_poses(args) -> int:
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
    print(f"{rep.summary()} -> {args.out} in {took(t0)}")
    return 0


def train_options(p: argparse._ActionsContainer, skip: tuple[str, ...] = ()) -> None:
    """Every TrainConfig field as an option (built from the dataclass: its defaults and help)."""
    from sparself.core.options import add_options
    from sparself.synthesis.train_config import TrainConfig

    add_options(p, TrainConfig, skip)


def train_config(args, skip: tuple[str, ...] = ()):
    from sparself.core.options import from_args
    from sparself.synthesis.train_config import TrainConfig

    return from_args(TrainConfig, args, skip)


def export_options(p: argparse.ArgumentParser) -> None:
    """How the dense scene is written (DensifyConfig's export fields), shared by `synthesize` and `densify`."""
    import dataclasses

    from sparself.core.options import add_options
    from sparself.pipeline import DensifyConfig

    export = ("downscaled", "triangulate")
    add_options(p, DensifyConfig, skip=tuple(f.name for f in dataclasses.fields(DensifyConfig) if f.name not in export))
