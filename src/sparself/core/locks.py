"""One writer per output: a command holds a lock on its ``--out`` from start to end, so that a second
command into the same place is refused in one line instead of mixing or replacing the first one's files.

The lock is a ``flock`` (the ``filelock`` library) on a hidden file beside the output, ``.NAME.lock``.
It is removed on release; a waiter that wins a lock on a removed file sees it and takes the new one.
Nested uses in one process (the CLI around the whole command, then ``atomic_dir`` inside it) share one hold.
"""

from __future__ import annotations

import contextlib
import logging
import os
from pathlib import Path
from typing import Iterator

from filelock import FileLock, Timeout

from sparself.core.errors import OutputError
from sparself.core.names import sibling_stem

log = logging.getLogger(__name__)

_held: dict[Path, int] = {}  # lock files this process holds -> how many nested holds


def lock_path(out: Path | str) -> Path:
    """The lock file of an output: ``.NAME.lock`` beside its real path (symlinks resolved)."""
    r = Path(os.path.realpath(os.path.abspath(os.fspath(out))))
    return r.parent / f".{sibling_stem(r.name)}.lock"


def _holder(path: Path) -> str:
    """' (process N)' from the lock file, where the holder wrote its id, else ''."""
    with contextlib.suppress(OSError, ValueError):
        pid = int(path.read_text().strip() or "x")
        return f" (process {pid})"
    return ""


def _same_file(path: Path, fd: int) -> bool:
    """Whether ``fd`` is still the file at ``path`` (a holder removes the file when it is done)."""
    try:
        return os.stat(path).st_ino == os.fstat(fd).st_ino
    except OSError:
        return False


def _acquire(path: Path, out: Path | str) -> FileLock:
    for _ in range(5):  # more than one retry means others keep taking and releasing it: refused below
        fds: list[int] = []

        def took(fd: int) -> None:
            fds.append(fd)
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())

        lock = FileLock(path, timeout=0, on_acquired=took, fallback_to_soft=False)
        try:
            lock.acquire()
        except Timeout:
            raise OutputError(
                f"{out}: another sparself command{_holder(path)} is writing it; wait for it to finish or "
                "choose another --out"
            ) from None
        if fds and _same_file(path, fds[-1]):
            return lock
        lock.release()  # won the lock on a file its holder had just removed
    raise OutputError(f"{out}: other sparself commands keep writing it; choose another --out")


def _make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; returns those created, deepest first. Raises OSError."""
    made = []
    p = folder
    while not p.exists():
        made.append(p)
        p = p.parent
    folder.mkdir(parents=True, exist_ok=True)
    return made


@contextlib.contextmanager
def output_lock(out: Path | str | None) -> Iterator[None]:
    """Hold the lock of ``out`` while the block runs (nothing when ``out`` is None). Refuses with an
    OutputError when another process holds it. Parent folders it had to create are removed after if
    they are still empty; a parent it cannot write to takes no lock (the output checks report it)."""
    if out is None:
        yield
        return
    path = lock_path(out)
    if path in _held:
        _held[path] += 1
        try:
            yield
        finally:
            _held[path] -= 1
        return
    made: list[Path] = []
    try:
        made = _make_parents(path.parent)
        lock = _acquire(path, out)
    except OutputError:
        _remove_empty(made)
        raise
    except OSError as e:  # a read-only parent, a file on the way: the command's own checks say so in their words
        log.debug("%s: no lock taken (%s)", out, e)
        _remove_empty(made)
        yield
        return
    _held[path] = 1
    try:
        yield
    finally:
        del _held[path]
        with contextlib.suppress(OSError):
            path.unlink()  # while still held, so a waiter can tell the file is gone
        lock.release()
        _remove_empty(made)


def _remove_empty(folders: list[Path]) -> None:
    for d in folders:
        with contextlib.suppress(OSError):
            d.rmdir()
