"""A folder of photos before SfM: which files are usable photos of one size, and the focal length their EXIF
data gives."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import numpy as np

from sparself.capture.images import (
    HEIF_EXTENSIONS,
    image_extensions,
    image_size_of,
    list_images,
    load_image,
    note_conversions,
)
from sparself.core.errors import InputError

log = logging.getLogger(__name__)


def validate_images(image_folder: Path, names: Sequence[str] | None = None) -> list[Path]:
    """Check a folder of photos before running COLMAP: at least 3 images, every one decodable, all the
    same size. -> image paths sorted by name. Raises InputError naming the offending files."""
    folder = Path(image_folder)
    if names is None:
        paths = list_images(folder)
    else:
        paths = [folder / n for n in names]
        missing = [str(p) for p in paths if not p.is_file()]
        if missing:
            raise InputError(f"image file(s) not found: {', '.join(missing)}")
    others = (
        sorted(
            p.name
            for p in folder.iterdir()
            if p.is_file()
            and p.suffix.lower() not in image_extensions() + HEIF_EXTENSIONS
            and not p.name.startswith(".")
        )
        if names is None
        else []
    )
    if others:
        log.info("%s: ignoring %d non-image file(s): %s", folder, len(others), ", ".join(others[:5]))
    if len(paths) < 3:
        raise InputError(
            f"{folder}: {len(paths)} image(s) found ({', '.join(p.name for p in paths)}); "
            "pose recovery needs at least 3 overlapping photos"
        )
    sizes: dict[tuple[int, int], list[str]] = {}
    bad = []
    for p in paths:
        try:
            load_image(p, warn=False)  # full decode: catches truncated files that a header read misses
            sizes.setdefault(image_size_of(p), []).append(p.name)
        except InputError as e:
            bad.append(str(e))
    if bad:
        raise InputError("; ".join(bad))
    note_conversions(paths)  # said here as training says it, once per kind with a count
    if len(sizes) > 1:
        main = max(sizes, key=lambda k: len(sizes[k]))
        odd = [f"{n} ({w}x{h})" for (w, h), ns in sizes.items() if (w, h) != main for n in ns]
        raise InputError(
            f"{folder}: images have different sizes: most are {main[0]}x{main[1]}, but "
            f"{', '.join(odd)}; use photos of one capture at one size (or resize them)"
        )
    return paths


def exif_focal_one(exif, width: int, height: int) -> float | None:
    """Focal length in px from one photo's EXIF: the 35 mm equivalent (f_px = f_35 / 43.27 mm x image
    diagonal), else the focal length in mm times the focal-plane resolution, scaled from the size the
    camera wrote (ExifImageWidth/Height) to the photo's size."""
    from PIL import ExifTags

    sub = exif.get_ifd(ExifTags.IFD.Exif)
    tag = lambda t: sub.get(t, exif.get(t))  # noqa: E731  (some writers put them in the main IFD)
    f35 = tag(ExifTags.Base.FocalLengthIn35mmFilm)
    if f35:
        return float(f35) / float(np.hypot(36.0, 24.0)) * float(np.hypot(width, height))
    f_mm, res, unit = (
        tag(ExifTags.Base.FocalLength),
        tag(ExifTags.Base.FocalPlaneXResolution),
        tag(ExifTags.Base.FocalPlaneResolutionUnit),
    )
    mm_per_unit = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}.get(int(unit or 2))
    exif_long = max(float(tag(ExifTags.Base.ExifImageWidth) or 0), float(tag(ExifTags.Base.ExifImageHeight) or 0))
    if not (f_mm and res and mm_per_unit and exif_long):
        return None
    # long side to long side: the photo may have been resized or turned upright since the camera wrote it
    return float(f_mm) * float(res) / mm_per_unit * max(width, height) / exif_long


def exif_focal_px(paths: Sequence[Path], width: int, height: int) -> float | None:
    """The focal length in px that the photos' EXIF gives at (width, height) (median over the photos that
    have one; :func:`exif_focal_one`), or None when none has one."""
    from PIL import Image

    vals = []
    for p in paths:
        try:
            with Image.open(p) as im:
                f = exif_focal_one(im.getexif(), width, height)
        except (OSError, SyntaxError, ValueError, ZeroDivisionError):
            continue
        if f and np.isfinite(f) and f > 0:
            vals.append(f)
    return float(np.median(vals)) if vals else None
