"""Safe output folders: results are written to a temporary sibling and renamed into place at the end,
so a failed or interrupted command leaves no partial output behind.

An output never equals, contains or lies inside one of the command's inputs (compared as real paths:
symlinks, ``.`` and ``..`` resolved), and ``--overwrite`` replaces only a folder that sparself wrote
(it holds :data:`MARKER`) or an empty one. Where the output folder cannot be renamed (a mount point),
its entries are moved in one by one, each with an atomic rename."""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import shutil
import stat
import tempfile
from pathlib import Path
from typing import Callable, Iterable, Iterator, NamedTuple

from sparself.core.errors import OutputError
from sparself.core.locks import output_lock
from sparself.core.names import sibling_stem

log = logging.getLogger(__name__)

MARKER = ".sparself-output"  # inside every folder sparself writes: what --overwrite may replace
_NO_RENAME = (errno.EBUSY, errno.EXDEV, errno.EPERM, errno.EACCES, errno.EINVAL)


class Input(NamedTuple):
    """An input of a command: what it is (for the message) and where. ``path`` None: not given."""

    what: str
    path: Path | str | None


def real(path: Path | str) -> Path:
    """The real path: relative parts, ``.``/``..`` and symlinks resolved (missing tails kept)."""
    return Path(os.path.realpath(os.path.abspath(os.fspath(path))))


def _shown(path: Path | str) -> str:
    r = real(path)
    return str(path) if str(path) == str(r) else f"{path} (= {r})"


def check_not_input(out: Path | str, inputs: Iterable[Input]) -> None:
    """Refuse an output that is, contains, or lies inside an input (one line naming both)."""
    r_out = real(out)
    for inp in inputs:
        if inp.path is None or str(inp.path) == "":
            continue
        r_in = real(inp.path)
        if r_out == r_in:
            how = "is"
        elif r_in.is_relative_to(r_out):
            how = "contains"
        elif r_out.is_relative_to(r_in):
            how = "lies inside"
        else:
            continue
        raise OutputError(
            f"output {_shown(out)} {how} the {inp.what} {_shown(inp.path)}; sparself never writes "
            "into or over its inputs: choose an --out outside them"
        )


def scene_folder(source: Path | str) -> Path:
    """The folder a scene lives in: beside its pose file, above ``sparse/0`` of a COLMAP model."""
    p = Path(source)
    if p.is_file():
        p = p.parent
    if p.name.isdigit() and p.parent.name == "sparse":
        p = p.parent
    return p.parent if p.name == "sparse" else p


def scene_inputs(scene, what: str = "scene") -> list[Input]:
    """A scene's folder (see :func:`scene_folder`; it holds the pose files), its image folders and the
    folders of its masks (read back with a dense scene). Linked images (``poses --link-images``) count
    where they really are: the photo folder behind the links is an input too."""
    found = []
    if getattr(scene, "source", None) is not None:
        found = [Input(f"{what} folder", scene_folder(scene.source))]
    folders = _folders_of(f.path for f in scene.frames)
    masks = _folders_of(f.mask for f in scene.frames) - folders
    return (
        found
        + [Input(f"{what}'s image folder", d) for d in sorted(folders)]
        + [Input(f"{what}'s mask folder", d) for d in sorted(masks)]
    )


def _folders_of(paths: Iterable[Path | str | None]) -> set[Path]:
    """The folders of ``paths`` and, for a symbolic link, the folder of the file it points to."""
    return {d for p in paths if p is not None for d in (Path(p).parent, real(p).parent)}


def evaluation_inputs(scenes: Iterable) -> list[Input]:
    """The inputs of an evaluation: each scene (a path, or a Scene's folders)."""
    found = []
    for s in scenes:
        found += scene_inputs(s) if hasattr(s, "frames") else [Input("scene", s)]
    return found


def check_output_dir(out: Path, overwrite: bool = False, inputs: Iterable[Input] = ()) -> None:
    """Before any work: refuse an output among the inputs, an existing non-empty folder (unless
    overwrite, and then only one sparself wrote that can be deleted), or a place we cannot write to."""
    out = Path(out)
    check_not_input(out, inputs)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise OutputError(f"{out}: folder exists and is not empty (use --overwrite to replace it)")
        if not (out / MARKER).is_file():
            raise OutputError(
                f"{out}: not a folder sparself wrote (no {MARKER} in it), so --overwrite does not "
                "replace it; delete it yourself or choose another --out"
            )
        _check_deletable(real(out))
        extra = added_since(out)
        if extra:
            log.warning(
                "%s: --overwrite also removes %d entr%s sparself did not write there: %s",
                out,
                len(extra),
                "y" if len(extra) == 1 else "ies",
                ", ".join(extra[:10]) + (f" and {len(extra) - 10} more" if len(extra) > 10 else ""),
            )
    if _in_place(real(out)):
        _check_writable_folder(out, real(out))
    else:
        _check_parent(out)


def _in_place(r_out: Path) -> bool:
    """A folder that cannot be renamed (a mount point) is filled in place, entry by entry."""
    return r_out.is_dir() and os.path.ismount(r_out)


def _check_deletable(r_out: Path) -> None:
    """--overwrite must be able to remove every entry of the old folder: refuse up front otherwise."""
    euid = os.geteuid() if hasattr(os, "geteuid") else -1
    parent = r_out.parent
    pst = parent.stat()
    if not _in_place(r_out) and not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{r_out}: cannot replace it: no permission to change {parent}")
    if pst.st_mode & stat.S_ISVTX and euid not in (0, pst.st_uid) and r_out.stat().st_uid != euid:
        raise OutputError(f"{r_out}: cannot replace it: {parent} is sticky and the folder belongs to another user")
    for d, dirs, files in os.walk(r_out):
        if not os.access(d, os.W_OK | os.X_OK):
            raise OutputError(f"{r_out}: --overwrite cannot delete it: no permission to change {d}")
        # root may delete anything except immutable files (os.access says no to those, even to root)
        for f in files if euid == 0 else ():
            p = os.path.join(d, f)
            if not os.path.islink(p) and not os.access(p, os.W_OK):
                raise OutputError(f"{r_out}: --overwrite cannot delete it: {p} is protected (immutable or read-only)")


def _check_writable_folder(out: Path, folder: Path) -> None:
    if not os.access(folder, os.W_OK) or not _can_create_in(folder, rename=False):
        raise OutputError(f"{out}: cannot write to {folder} (permission denied or read-only)")


def _check_parent(out: Path) -> None:
    """The nearest existing ancestor of ``out`` must be a folder we can create and rename things in."""
    probe = real(out).parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{out}: cannot create it, {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK) or not _can_create_in(probe):
        raise OutputError(f"{out}: cannot write to {probe} (permission denied or read-only)")


def _can_create_in(folder: Path, rename: bool = True) -> bool:
    """Really try (os.access says yes to root on read-only file systems): make, rename, remove a folder."""
    try:
        d = tempfile.mkdtemp(prefix=".sparself-probe-", dir=folder)
        if rename:
            os.rename(d, d + "-renamed")
            d += "-renamed"
        os.rmdir(d)
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
    """Remove temporary siblings of ``out`` (or, for a mount point, temporary entries inside it) left by a
    process that no longer runs (killed with SIGKILL, or a power cut: no ``except`` clause ran to clean
    up). Returns what was removed."""
    out = Path(out)
    removed = []
    r_out = real(out)
    prefix = f".{sibling_stem(r_out.name)}.tmp-"
    for parent in (r_out.parent, r_out):
        if not parent.is_dir():
            continue
        for p in parent.glob(f"{prefix}*"):
            pid = p.name[len(prefix) :].split("-", 1)[0]
            if pid.isdigit() and int(pid) != os.getpid() and not _pid_alive(int(pid)):
                shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
                removed.append(p)
                log.info("removed %s, left by an interrupted run (process %s)", p, pid)
    return removed


def _make_temp(out: Path, make, inside: bool = False) -> Path:
    """Create the parent folders and a temporary sibling of ``out`` (inside ``out`` when ``inside``) with
    ``make(prefix, dir)``; an OSError becomes an OutputError naming ``out``. The prefix holds our process
    id, so that a later run can tell a dead run's leftovers (removed) from a live run's folder (kept)."""
    r_out = real(out)
    try:
        r_out.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temps(out)
        return Path(make(f".{sibling_stem(r_out.name)}.tmp-{os.getpid()}-", r_out if inside else r_out.parent))
    except OSError as e:
        raise OutputError(f"{out}: cannot write there ({e.strerror or e})") from None


@contextlib.contextmanager
def scratch_dir(out: Path | str | None, tag: str) -> Iterator[Path]:
    """A folder for intermediate files, removed after: beside ``out`` and named as its temporary folders
    (so that a later run removes it when this process is killed), or in the system temp when ``out`` is None."""

    def make(prefix: str, folder: Path | None) -> str:
        return tempfile.mkdtemp(prefix=f"{prefix}{tag}-", dir=folder)

    d = Path(make("sparself-", None)) if out is None else _make_temp(Path(out), make, inside=_in_place(real(out)))
    try:
        yield d
    finally:
        shutil.rmtree(d, ignore_errors=True)


_working: list[Path] = []  # the work folders of the blocks running in this process, innermost last


def current_work() -> Path | None:
    """The work folder of the innermost :func:`work_dir` block running in this process (None outside one): where
    long steps keep what they finish (fits, training runs) for a stopped command to resume from."""
    return _working[-1] if _working else None


def finished_work(folder: Path) -> bool:
    """Whether a work folder holds a finished step: a kept value (``*.pkl``) or a checkpoint (``*.pt``)."""
    return any(p.suffix in (".pkl", ".pt") for p in folder.rglob("*") if p.is_file())


def work_path(out: Path | str) -> Path:
    """Where a long command keeps its finished steps for ``out``: ``.NAME.sparself-work`` beside it."""
    r_out = real(out)
    return r_out.parent / f".{sibling_stem(r_out.name)}.sparself-work"


@contextlib.contextmanager
def work_dir(
    out: Path | str, resume: bool, worth_keeping: Callable[[Path], bool] = finished_work
) -> Iterator[Path | None]:
    """The block's work folder for ``out`` (:func:`work_path`), marked as sparself's: the one a stopped run left
    when ``resume``, else a new one (a stopped run's is removed first). It is removed when the block ends, and
    kept after an error or an interrupt when ``worth_keeping(folder)``, for the next run to resume from. None
    (nothing is kept) when ``out`` is a mount point, filled in place: no folder of ours may stand inside it."""
    r_out = real(out)
    if _in_place(r_out):
        yield None
        return
    path = work_path(out)
    if path.exists() and not (path / MARKER).is_file():
        raise OutputError(f"{path}: in the way of the work folder of {out}, and sparself did not write it; move it")
    if path.exists() and not resume:
        log.info("%s: removing what a stopped run left there (--resume continues from it)", path)
        shutil.rmtree(path)
    elif resume and path.exists():
        log.info("resuming from %s", path)
    elif resume:  # not a warning: a batch resumes every unit, most of them never stopped
        log.info("%s: no stopped run to resume (nothing in %s); starting from the beginning", out, path)
    path.mkdir(parents=True, exist_ok=True)
    write_marker(path)
    _working.append(path)
    try:
        yield path
    except BaseException as e:
        if not worth_keeping(path):
            shutil.rmtree(path, ignore_errors=True)
        elif not isinstance(e, KeyboardInterrupt):  # an interrupted command's last line says it
            log.warning("%s: the finished steps are kept in %s; the same command with --resume continues", out, path)
        raise
    finally:
        _working.remove(path)
    shutil.rmtree(path, ignore_errors=True)


def _usual_mode(path: Path, mode: int) -> None:
    """Give ``path`` ``mode`` less the process umask (what a plain open/mkdir would have made)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, mode & ~umask)


def write_marker(folder: Path, entries: Iterable[str] = ()) -> None:
    """Mark ``folder`` as written by sparself (what --overwrite may replace), listing the ``entries`` it
    wrote there (so that --overwrite can name what a user added since)."""
    from sparself import __version__

    head = f"written by sparself {__version__}; --overwrite may replace this folder\n"
    (Path(folder) / MARKER).write_text(head + "".join(f"{_LISTED}{e}\n" for e in sorted(entries)))


_LISTED = "wrote: "


def added_since(folder: Path) -> list[str]:
    """Entries of a sparself folder that its marker does not list (put there by someone else); [] when
    the marker lists nothing (written by an older version, or a run folder that grows as it trains)."""
    try:
        listed = [
            ln[len(_LISTED) :] for ln in (Path(folder) / MARKER).read_text().splitlines() if ln.startswith(_LISTED)
        ]
    except OSError:
        return []
    return sorted(p.name for p in Path(folder).iterdir() if p.name not in {MARKER, *listed}) if listed else []


def _remove(p: Path) -> None:
    shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()


def _move_into(src: Path, folder: Path) -> None:
    """Move ``src`` to ``folder/src.name`` with one atomic rename; across file systems, copy it to a
    temporary name inside ``folder`` first and rename that."""
    dst = folder / src.name
    try:
        os.replace(src, dst)
        return
    except OSError as e:
        if e.errno != errno.EXDEV:
            raise
    staged = folder / f".{sibling_stem(folder.name)}.tmp-{os.getpid()}-{src.name}"
    if src.is_dir() and not src.is_symlink():
        shutil.copytree(src, staged, symlinks=True)
    else:
        shutil.copy2(src, staged, follow_symlinks=False)
    os.replace(staged, dst)
    _remove(src)


def fill_in_place(tmp: Path, r_out: Path) -> None:
    """Where ``r_out`` cannot be replaced by a rename: empty it (it was checked as replaceable), then move
    the entries of ``tmp`` in one by one, the marker first, each with an atomic rename."""
    r_out.mkdir(parents=True, exist_ok=True)
    old = [p for p in r_out.iterdir() if p != tmp]
    if old and not (r_out / MARKER).is_file():
        raise OutputError(f"{r_out}: files that sparself did not write appeared there while this command ran")
    for p in old:
        _remove(p)
    entries = sorted(tmp.iterdir(), key=lambda p: (p.name != MARKER, p.name))
    for p in entries:
        _move_into(p, r_out)
    shutil.rmtree(tmp, ignore_errors=True)


def identity(path: Path | str) -> tuple[int, int] | None:
    """(device, inode) of what is at ``path`` now (None: nothing): tells the folder checked at the start
    from one that appeared there while the command ran."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def _put_aside(r_out: Path, checked: tuple[int, int] | None) -> Path | None:
    """Rename the old output aside, if it is the folder checked at the start and still only holds what
    sparself wrote (or nothing); whatever else is there is left in place (the rename over it then fails)."""
    if checked is None or identity(r_out) != checked:
        return None
    old = r_out.parent / f".{sibling_stem(r_out.name)}.tmp-{os.getpid()}-old"
    os.rename(r_out, old)
    if (old / MARKER).is_file() or not any(old.iterdir()):
        return old
    os.rename(old, r_out)  # filled by someone else meanwhile: not ours to delete
    return None


_TAKEN = (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR)  # rename onto something that is there


def _swap_in(tmp: Path, r_out: Path, checked: tuple[int, int] | None) -> None:
    """Rename ``tmp`` to ``r_out``; the old output (``checked``: the one found at the start) is renamed
    aside first and removed after, so that a failed rename puts it back. A rename never replaces a
    non-empty folder, so one that appeared at ``r_out`` meanwhile survives: the result is then kept
    beside it and an OutputError says where. Raises OSError (EBUSY, EXDEV, ...) when ``r_out`` cannot
    be renamed."""
    old = _put_aside(r_out, checked)
    try:
        os.rename(tmp, r_out)
    except OSError as e:
        if old is not None:
            os.rename(old, r_out)
        if e.errno in _TAKEN:
            kept = r_out.parent / f"{sibling_stem(r_out.name, room=32)}.sparself-{os.getpid()}"
            os.rename(tmp, kept)
            raise OutputError(
                f"{r_out}: something else was put there while this command ran, so it was left as it is; "
                f"the result is in {kept}"
            ) from None
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
        if old.exists():
            log.warning("%s: could not remove all of the replaced output (left in %s)", r_out, old)


@contextlib.contextmanager
def atomic_dir(out: Path, overwrite: bool = False, inputs: Iterable[Input] = ()) -> Iterator[Path]:
    """Yield a temporary folder beside ``out``; on success it replaces ``out``, on error it is removed.
    ``out`` may be a symlink: the folder it points to is written. A mount point is filled in place."""
    out = Path(out)
    with output_lock(out):
        check_output_dir(out, overwrite, inputs)
        r_out = real(out)
        checked = identity(r_out)
        inside = _in_place(r_out)
        tmp = _make_temp(out, lambda prefix, d: tempfile.mkdtemp(prefix=prefix, dir=d), inside=inside)
        _usual_mode(tmp, 0o777)  # mkdtemp makes 0700
        try:
            write_marker(tmp)
            yield tmp
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        _finish(out, tmp, r_out, checked, inside)


def _finish(out: Path, tmp: Path, r_out: Path, checked: tuple[int, int] | None, inside: bool) -> None:
    """Put the finished ``tmp`` in place of ``r_out`` (see :func:`_swap_in`); on failure remove it."""
    try:
        write_marker(tmp, [p.name for p in tmp.iterdir() if p.name != MARKER])
        if inside:
            fill_in_place(tmp, r_out)
            return
        try:
            _swap_in(tmp, r_out, checked)
        except OSError as e:
            if e.errno not in _NO_RENAME:
                raise
            log.info("%s: cannot be renamed (%s); writing into it entry by entry", out, e.strerror)
            fill_in_place(tmp, r_out)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise OutputError(f"{out}: cannot write the result there ({e.strerror or e})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextlib.contextmanager
def atomic_file(path: Path, inputs: Iterable[Input] = ()) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; it is renamed to ``path`` on success, removed on error."""
    path = Path(path)
    check_not_input(path, inputs)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, expected a file path")
    _check_parent(path)

    def make(prefix: str, d: Path) -> str:
        fd, name = tempfile.mkstemp(prefix=prefix, dir=d, suffix=path.suffix)
        os.close(fd)
        return name

    tmp = _make_temp(path, make)
    _usual_mode(tmp, 0o666)  # mkstemp makes 0600; results should get the usual file mode
    try:
        yield tmp
    except RuntimeError:  # torch.save reports a full disk as a RuntimeError ("file write failed")
        full = shutil.disk_usage(tmp.parent).free < 2**20
        tmp.unlink(missing_ok=True)
        if full:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path)) from None
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, real(path))
