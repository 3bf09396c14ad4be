"""Names that come from input files (plan frames, image names in COLMAP models, transforms.json,
LLFF and Middlebury folders) become file names in an output folder. They are checked here, once, by
every reader and the plan loader, before anything is written: a name can never lead outside ``--out``
(no separators, no ``..``, no absolute paths) nor overwrite another view (no two names equal after case
folding: they are one file on macOS and Windows)."""

from __future__ import annotations

import hashlib
import os
import unicodedata
from typing import Iterable

from natsort import natsort_keygen, ns

from sparself.core.errors import InputError

_MAX_BYTES = 255  # a file name's limit on common file systems


def name_problem(name: object, *, subfolders: bool = False) -> str | None:
    """What is wrong with ``name`` as a file name inside an output folder, or None.

    subfolders: allow relative ``a/b.png`` names (COLMAP image names may be), each part checked."""
    if not isinstance(name, str):
        return f"is a {type(name).__name__}, not a text"
    if not name.strip():
        return "is empty"
    if any(unicodedata.category(c) == "Cc" for c in name):
        return "contains a control character"
    if name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":" and name[0].isalpha()):
        return "is an absolute path; expected a plain file name"
    if "\\" in name:
        return "contains a path separator '\\'; expected a plain file name"
    parts = name.split("/")
    if ".." in parts:
        return "contains '..'; expected a plain file name"
    if len(parts) > 1 and not subfolders:
        return "contains a path separator '/'; expected a plain file name"
    if any(p in ("", ".") for p in parts):
        return "has an empty or '.' part"
    if any(len(p.encode("utf-8", "surrogateescape")) > _MAX_BYTES for p in parts):
        return f"is longer than {_MAX_BYTES} bytes"
    return None


def check_names(
    names: Iterable[object],
    where: object,
    *,
    what: str = "image name",
    subfolders: bool = False,
    extensions: Iterable[str] | None = None,
    taken: Iterable[str] = (),
) -> None:
    """Raise InputError naming ``where`` and the first bad or colliding name.

    extensions: when given, each name must end with one of them (case-insensitive).
    taken: names of the scene's own views, which ``names`` must not collide with."""
    exts = tuple(e.lower() for e in extensions) if extensions is not None else None
    views = {unicodedata.normalize("NFC", t).casefold(): t for t in taken}
    seen: dict[str, str] = {}
    for name in names:
        problem = name_problem(name, subfolders=subfolders)
        if problem:
            raise InputError(f"{where}: {what} {name!r} {problem}")
        assert isinstance(name, str)  # name_problem names anything that is not text
        if exts is not None and os.path.splitext(name)[1].lower() not in exts:
            raise InputError(f"{where}: {what} {name!r} does not end with an image extension ({', '.join(exts)})")
        key = unicodedata.normalize("NFC", name).casefold()
        if key in views:
            raise InputError(
                f"{where}: {what} {name!r} is the name of a view of the scene ({views[key]!r}); "
                "each view needs its own file name"
            )
        if key in seen:
            twice = (
                "appears twice"
                if seen[key] == name
                else f"and {seen[key]!r} differ only in case (one file on macOS and Windows)"
            )
            raise InputError(f"{where}: {what} {name!r} {twice}")
        seen[key] = name


def capture_key(name: str):
    """Sort key of a file name in capture order: numbers compared as numbers (``IMG_2`` before ``IMG_10``,
    as phones and video exports name frames without zero padding), case ignored."""
    return _NATURAL(name)


_NATURAL = natsort_keygen(alg=ns.IGNORECASE)


def sibling_stem(name: str, room: int = 64) -> str:
    """``name`` as the stem of sparself's hidden siblings of it (temporary folders, the lock: up to ``room``
    bytes more), so that they keep within the file-name limit: a long name is cut, with a hash of the whole
    (the same name always gives the same stem, so a later run finds a killed run's leftovers)."""
    raw = name.encode()
    if len(raw) + room <= _MAX_BYTES:
        return name
    digest = hashlib.sha1(raw).hexdigest()[:8]
    return raw[: _MAX_BYTES - room - len(digest) - 1].decode(errors="ignore") + "~" + digest
