"""Command-line interface: the parser, logging, and the one-line errors and exit codes. Each command calls one
library function.

To add a command: write ``add_<name>(sub)`` that builds its parser and sets ``func`` to a ``run_<name>(args)``
that calls the library (in :mod:`sparself.commands`, or :mod:`sparself.commands_synthesis` for the network's
commands), then list it in ``COMMANDS``.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys

from sparself import __version__, commands, commands_synthesis
from sparself.core.errors import SparselfError
from sparself.core.interrupts import signals_interrupt, stopped_by
from sparself.core.locks import output_lock
from sparself.core.logs import BarSafeHandler, Repeats
from sparself.core.space import os_error_line

log = logging.getLogger("sparself")

# libgomp's threads (torch's, two here) spin 300,000 times after each parallel region before they sleep. Beside the
# fit workers on the same cores that spinning is taken from the fits: a fixer training of 2 s alone took 48 s
# beside two 300-step fits, and the fits 45 s instead of 22. With a short spin the training took 4.5 s there and
# the fits 32 s, and alone each is as fast as before. Only when threads wait: the numbers are the same.
OPENMP_SPIN = "10000"


def short_openmp_spin() -> None:
    """Set libgomp's spin count for this process, unless the user has set one. It is read once, when torch loads:
    a command sets it before that, and a process that has loaded torch already keeps what it has."""
    if "torch" not in sys.modules:
        os.environ.setdefault("GOMP_SPINCOUNT", OPENMP_SPIN)


COMMANDS = (  # in the order `sparself --help` lists them
    commands.add_info,
    commands.add_plan,
    commands.add_evaluate,
    commands.add_poses,
    commands_synthesis.add_train,
    commands_synthesis.add_synthesize,
    commands_synthesis.add_densify,
    commands_synthesis.add_batch,
)


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
    for add in COMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    short_openmp_spin()
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


# ---- train / synthesize / densify (the CNN–LSTM synthesizer) ----------------------------------------


# ---- batch: many captures as Ray tasks --------------------------------------------------------------


if __name__ == "__main__":
    sys.exit(main())
