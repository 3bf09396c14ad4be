"""Disk space and path limits, said in one line: a long command checks the free space of its output's file
system before it starts, and a full disk or an over-long path part met later is reported the same way
(the command's temporary output is removed as on any failure)."""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

from sparself.core.errors import OutputError

MB = 2**20
_needed: dict[str, int] = {}  # the estimate of the running command, for the message of a full disk met later


def _existing(path: Path | str) -> Path:
    p = Path(os.path.realpath(os.path.abspath(os.fspath(path))))
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def device_of(path: Path | str) -> Path:
    """The mount point of the file system ``path`` (or its nearest existing ancestor) is on."""
    p = _existing(path)
    while not os.path.ismount(p) and p != p.parent:
        p = p.parent
    return p


def _message(path: Path | str, needed: int | None, free: int | None = None) -> str:
    about = f"needed about {max(1, round(needed / MB))} MB" if needed else "needed more"
    left = f", {free / MB:.0f} MB free" if free is not None else ""
    return f"no space left on {device_of(path)} ({about}{left})"


def check_free_space(out: Path | str, needed: int) -> None:
    """Before long work: refuse when the file system of ``out`` has less than ``needed`` bytes free."""
    _needed["bytes"] = int(needed)
    free = shutil.disk_usage(_existing(out)).free
    if free < needed:
        raise OutputError(_message(out, needed, free))


def files_size(paths) -> int:
    """Bytes of the files in ``paths`` (links followed; missing ones count 0)."""
    total = 0
    for p in paths:
        try:
            total += os.stat(p).st_size
        except (OSError, TypeError):
            pass
    return total


def os_error_line(e: OSError, out: Path | str | None) -> str | None:
    """One line for an OSError a user can act on (a full disk, a path part over the file system's limit),
    else None (a bug: the traceback stays)."""
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        return _message(e.filename or out or ".", _needed.get("bytes"))
    if e.errno == errno.ENAMETOOLONG:
        where = e.filename or out
        return f"{where}: a part of this path is longer than the file system allows (255 bytes); use a shorter name"
    return None
