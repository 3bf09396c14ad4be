"""The photos as COLMAP reads them in the SfM work folder: each under an alias that sorts in capture order,
and every name COLMAP returns mapped back to the user's.

COLMAP orders images by their names as text, and its sequential matcher pairs each image with the next ones
in that order: ``IMG_2 ... IMG_10`` would be paired as ``IMG_10, IMG_11, ..., IMG_2``, so neighbours in
capture order would never be matched. Under aliases made of the zero-padded capture rank (``0002.jpg``),
COLMAP's text order is capture order (:func:`sparself.core.names.capture_key`) for any names.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from sparself.capture.images import load_image, needs_conversion, save_image
from sparself.core.names import capture_key

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class WorkImages:
    """The folder COLMAP reads and the names it knows the photos by.

    folder: the photos under their aliases (links to them, or upright RGB copies).
    aliases: COLMAP's name of every photo, in capture order.
    user: the user's name of each alias."""

    folder: Path
    aliases: tuple[str, ...]
    user: dict[str, str]

    def to_user_names(self, rec):
        """A pycolmap reconstruction's images renamed, in place, from aliases to the user's names. -> rec."""
        for img in rec.images.values():
            img.name = self.user[img.name]
        return rec


def alias_names(names: Sequence[str]) -> dict[str, str]:
    """COLMAP's name of each photo: its rank in capture order, zero-padded so that text order is capture order,
    with the photo's extension (``IMG_10.JPG`` -> ``0010.JPG``)."""
    ordered = sorted(names, key=capture_key)
    width = max(4, len(str(len(ordered) - 1)))
    return {n: f"{k:0{width}d}{Path(n).suffix}" for k, n in enumerate(ordered)}


def work_images(paths: Sequence[Path], work: Path) -> WorkImages:
    """``work/images`` with every photo of ``paths`` under its alias. COLMAP ignores EXIF orientation and reads
    grayscale, 16-bit, RGBA or CMYK files its own way, while sparself's image loading turns every photo into
    upright RGB; so such photos reach COLMAP as upright RGB copies (made by the same loader), and the recovered
    cameras match the images as every other stage sees them. The others are links: nothing is copied."""
    alias = alias_names([p.name for p in paths])
    odd = [p for p in paths if needs_conversion(p)]
    if odd:
        log.info(
            "sfm: %d photo(s) need conversion (%s); COLMAP reads upright RGB copies",
            len(odd),
            ", ".join(p.name for p in odd[:5]),
        )
    folder = work / "images"
    folder.mkdir()
    for p in paths:
        if p in odd:
            save_image(folder / alias[p.name], load_image(p, warn=False))
        else:
            (folder / alias[p.name]).symlink_to(p.resolve())
    aliases = tuple(sorted(alias.values()))
    return WorkImages(folder, aliases, {a: n for n, a in alias.items()})
