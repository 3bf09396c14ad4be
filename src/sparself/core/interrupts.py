"""SIGTERM and SIGHUP as Ctrl-C: one mechanism for every command, the batch included.

`kill`, `timeout` and container stops send SIGTERM; a closed terminal sends SIGHUP. Turned into
KeyboardInterrupt, they take the same path as Ctrl-C (temporary output removed, checkpoint kept), and
:func:`stopped_by` tells the caller which signal it was, for the exit status 128 + signal.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator

STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))
_stopped_by: list[int] = []  # the signals that stopped the running command, in order


def _stop(signum, frame) -> None:
    for s in STOP_SIGNALS:  # a second signal must not interrupt the cleanup of the first
        signal.signal(s, signal.SIG_IGN)
    _stopped_by.append(signum)
    raise KeyboardInterrupt


def stopped_by() -> int:
    """The signal that stopped the command: SIGTERM or SIGHUP, else SIGINT (Ctrl-C)."""
    return _stopped_by[-1] if _stopped_by else int(signal.SIGINT)


@contextlib.contextmanager
def signals_interrupt(reset: bool = True) -> Iterator[None]:
    """While the block runs, SIGTERM and SIGHUP raise KeyboardInterrupt; the old handlers come back after
    (so that in-process callers, tests among them, keep theirs). Outside the main thread it does nothing.
    reset=False keeps the record of an earlier signal (a nested use, e.g. re-installed after ray.init)."""
    if reset:
        _stopped_by.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _stop) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def import_native(name: str):
    """Import a module whose native code installs its own handler for SIGTERM on import (pycolmap: glog
    prints a C++ stack and kills the process, so no cleanup runs), then put the Python handlers back."""
    import importlib

    before = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    module = importlib.import_module(name)
    if threading.current_thread() is threading.main_thread():
        for s, h in before.items():
            if h is not None:
                signal.signal(s, h)  # the C-level handler again, where the import replaced it
    return module
