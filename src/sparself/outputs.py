"""Safe output folders: results are written to a temporary sibling and renamed into place at the end,
so a failed or interrupted command leaves no partial output behind."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from .errors import OutputError

log = logging.getLogger(__name__)


def check_output_dir(out: Path, overwrite: bool = False) -> None:
    """Refuse an existing non-empty folder (unless overwrite) or an unwritable parent, before any work."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise OutputError(f"{out}: folder exists and is not empty (use --overwrite to replace it)")
    _check_parent(out)


def _check_parent(out: Path) -> None:
    """The nearest existing ancestor of ``out`` must be a folder we can create things in."""
    probe = Path(out).resolve().parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{out}: cannot create it, {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK) or not _can_create_in(probe):
        raise OutputError(f"{out}: cannot write to {probe} (permission denied or read-only)")


def _can_create_in(folder: Path) -> bool:
    """Really try (os.access says yes to root on read-only file systems): make and remove a folder."""
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".sparself-probe-", dir=folder))
        return True
    except OSError:
        return False


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by someone else
        return True
    return True


def remove_stale_temps(out: Path) -> list[Path]:
    """Remove temporary siblings of ``out`` left by a process that no longer runs (killed with
    SIGKILL, or a power cut: no ``except`` clause ran to clean up). Returns what was removed."""
    out = Path(out)
    removed = []
    parent = out.resolve().parent
    if not parent.is_dir():
        return removed
    for p in parent.glob(f".{out.name}.tmp-*"):
        pid = p.name[len(f".{out.name}.tmp-"):].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _pid_alive(int(pid)):
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
            removed.append(p)
            log.info("removed %s, left by an interrupted run (process %s)", p, pid)
    return removed


def _make_temp(out: Path, make) -> Path:
    """Create the parent folders and a temporary sibling of ``out`` with ``make(prefix, dir)``;
    an OSError becomes an OutputError naming ``out``. The prefix holds our process id, so that a
    later run can tell a dead run's leftovers (removed) from a live run's folder (kept)."""
    try:
        out.resolve().parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temps(out)
        return Path(make(f".{out.name}.tmp-{os.getpid()}-", out.resolve().parent))
    except OSError as e:
        raise OutputError(f"{out}: cannot write there ({e.strerror or e})") from None


@contextlib.contextmanager
def atomic_dir(out: Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder beside ``out``; on success it replaces ``out``, on error it is removed."""
    out = Path(out)
    check_output_dir(out, overwrite)
    tmp = _make_temp(out, lambda prefix, d: tempfile.mkdtemp(prefix=prefix, dir=d))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes 0700
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)


@contextlib.contextmanager
def atomic_file(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; it is renamed to ``path`` on success, removed on error."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, expected a file path")
    _check_parent(path)

    def make(prefix: str, d: Path) -> str:
        fd, name = tempfile.mkstemp(prefix=prefix, dir=d, suffix=path.suffix)
        os.close(fd)
        return name

    tmp = _make_temp(path, make)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; results should get the usual file mode
    try:
        yield tmp
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)
