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


if __name__ == "__main__":
    sys.exit(main())
