"""Command-line interface: argument parsing only. Each command calls one library function.

To add a command: write ``_add_<name>(sub)`` that builds its parser and sets ``func`` to a
``_run_<name>(args)`` that calls the library, then list it in ``_COMMANDS``.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from . import __version__
from .errors import SparselfError

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
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    level = logging.DEBUG if args.debug else (logging.WARNING if args.quiet else logging.INFO)
    logging.basicConfig(level=level, format="%(levelname)s: %(message)s", stream=sys.stderr, force=True)
    try:
        return int(args.func(args) or 0)
    except SparselfError as e:
        if args.debug:
            raise
        print(f"sparself {args.command}: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print(f"sparself {args.command}: interrupted", file=sys.stderr)
        return 130


# ---- commands ------------------------------------------------------------------------------------
# (each helper appends its _add_* function here and to _COMMANDS)


def _add_info(sub) -> None:
    p = sub.add_parser(
        "info", help="describe a scene: views, image size, cameras, field of view, pose bounds",
        description="Print what a scene holds: number of views, image size, camera model and intrinsics, "
                    "field of view, camera-centre extent, depth bounds and scene scale. SCENE is a COLMAP "
                    "model folder, an LLFF folder (poses_bounds.npy), a transforms.json or a Middlebury set.")
    p.add_argument("scene", type=Path, help="scene folder or pose file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    _common(p)
    p.set_defaults(func=_run_info)


def _run_info(args) -> int:
    from .info import describe

    print(describe(args.scene, as_json=args.json))
    return 0


_COMMANDS.append(_add_info)


def _add_plan(sub) -> None:
    p = sub.add_parser(
        "plan", help="plan novel camera poses (midpoints + extrapolations) for a scene",
        description="The paper's novel-pose plan: camera centres are LERPed and rotations SLERPed on the "
                    "shortest arc, at t=0.5 between consecutive views and t=1.2 past both ends of the path "
                    "(8 + 2 = 10 poses by default). Writes a JSON plan; --plot draws the cameras.")
    p.add_argument("scene", type=Path, help="scene folder or pose file")
    p.add_argument("--out", type=Path, required=True, help="plan file to write (JSON)")
    p.add_argument("--n-mid", type=int, default=8, help="midpoints between consecutive views (default 8)")
    p.add_argument("--n-extra", type=int, default=2, help="extrapolated poses past the ends (default 2)")
    p.add_argument("--order", choices=["auto", "capture", "nearest"], default="auto",
                   help="which views are consecutive: capture order, a nearest-neighbour path, or auto "
                        "(capture order unless it walks 1.5x further than the nearest-neighbour path)")
    p.add_argument("--gaps", choices=["even", "largest"], default="even",
                   help="which gaps get midpoints: spread evenly (default) or the widest ones")
    p.add_argument("--plot", type=Path, default=None, help="also draw the cameras to this PNG")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    _common(p)
    p.set_defaults(func=_run_plan)


def _run_plan(args) -> int:
    from .plan import PlanConfig, make_plan

    frames = make_plan(args.scene, args.out, PlanConfig(n_mid=args.n_mid, n_extra=args.n_extra,
                                                        order=args.order, gaps=args.gaps),
                       plot=args.plot, overwrite=args.overwrite)
    print(f"planned {len(frames)} novel poses -> {args.out}" + (f" (plot: {args.plot})" if args.plot else ""))
    return 0


_COMMANDS.append(_add_plan)


if __name__ == "__main__":
    sys.exit(main())
