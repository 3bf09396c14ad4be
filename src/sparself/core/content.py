"""What a value holds, compared and named: equality field by field and arrays element by element
(:func:`same_content`), a digest of the same walk (:func:`digest`, the key of work kept on disk), and that work
itself written whole or not at all (:func:`keep`, :func:`kept`)."""

from __future__ import annotations

import hashlib
import logging
import pickle
from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sparself.core.errors import OutputError
from sparself.core.outputs import atomic_file

log = logging.getLogger(__name__)


def same_content(a, b) -> bool:
    """Whether two values are equal field by field, arrays element by element (dataclasses such as a Scene and its
    frames, dicts, lists, tuples, arrays, and anything else by ``==``)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    if is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(same_content(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same_content(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(same_content(x, y) for x, y in zip(a, b))
    return bool(a == b)


def digest(value) -> str:
    """A hex SHA-256 of ``value``'s content, walked as :func:`same_content` compares it; a path also gives its
    file's size and modification time, so that an edited file gets a new digest. Values without a dataclass,
    array, container, path or plain scalar form go in by ``repr`` (one that names a memory address differs from
    run to run: a miss, never a wrong match)."""
    h = hashlib.sha256()
    _feed(h, value)
    return h.hexdigest()


def _feed(h, v) -> None:
    h.update(type(v).__qualname__.encode() + b":")
    if isinstance(v, np.ndarray):
        h.update(f"{v.dtype.str}{v.shape}".encode())
        h.update(np.ascontiguousarray(v).tobytes())
    elif is_dataclass(v) and not isinstance(v, type):
        for f in fields(v):
            h.update(f.name.encode() + b"=")
            _feed(h, getattr(v, f.name))
    elif isinstance(v, dict):
        h.update(f"{len(v)}".encode())
        for k in sorted(v, key=repr):  # equal dicts in another order are the same content
            _feed(h, k)
            _feed(h, v[k])
    elif isinstance(v, (list, tuple)):
        h.update(f"{len(v)}".encode())
        for x in v:
            _feed(h, x)
    elif isinstance(v, Path):
        st = v.stat() if v.is_file() else None
        h.update(repr((str(v), st and (st.st_size, st.st_mtime_ns))).encode())
    else:
        h.update(repr(v).encode())
    h.update(b";")


def keep(path: Path, value: Any) -> bool:
    """Pickle ``value`` to ``path``, whole or not at all (:func:`~sparself.core.outputs.atomic_file`); False, with
    the reason at debug level, when it cannot be pickled or written."""
    try:
        with atomic_file(Path(path)) as tmp, open(tmp, "wb") as f:
            pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
        return True
    except (OSError, OutputError, pickle.PicklingError, TypeError, AttributeError) as e:
        log.debug("%s: not kept (%s)", path, e)
        return False


def kept(path: Path) -> Any | None:
    """What :func:`keep` wrote to ``path``; None when there is nothing there or it cannot be read back (a file
    from another version of the code, say: the work is then done again)."""
    try:
        with open(path, "rb") as f:
            return pickle.load(f)
    except FileNotFoundError:
        return None
    except Exception as e:  # unpickling fails in many ways; each means only that the work is done again
        log.debug("%s: cannot be read back (%s); doing that work again", path, e)
        return None
