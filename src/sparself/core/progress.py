"""Whether to draw progress bars: only on a terminal, and not under ``-q`` (the "sparself" logger above INFO).

A bar written into a log file is a heap of carriage returns and escape codes, so without a terminal the
commands log a line per checkpoint instead.
"""

from __future__ import annotations

import logging
import sys


def show_progress() -> bool:
    """True when stderr is a terminal and info messages are shown (no ``-q``)."""
    try:
        tty = sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stderr
        tty = False
    return tty and logging.getLogger("sparself").isEnabledFor(logging.INFO)
