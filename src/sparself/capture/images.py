"""Image files: which a folder holds, how they are decoded to upright RGB (said once per folder), resized and
written."""

from __future__ import annotations

import functools
import logging
import os
from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from sparself.core.errors import InputError
from sparself.core.names import capture_key

log = logging.getLogger(__name__)

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
_WARNED: set[tuple[str, str]] = set()  # (folder, conversion) already said


HEIF_EXTENSIONS = (".heic", ".heif")


@functools.cache
def heif_readable() -> bool:
    """HEIC/HEIF photos (iPhones) are read when pillow-heif is installed (it registers a PIL opener);
    it is not a dependency of sparself."""
    try:
        from pillow_heif import register_heif_opener
    except ImportError:
        return False
    register_heif_opener()
    return True


def image_extensions() -> tuple[str, ...]:
    """Suffixes of the image files sparself reads (HEIC/HEIF too when pillow-heif is installed)."""
    return IMAGE_EXTENSIONS + (HEIF_EXTENSIONS if heif_readable() else ())


def image_files(folder: Path) -> list[Path]:
    # names starting with "." are hidden files: macOS AppleDouble "._IMG_0001.JPG" (resource-fork metadata,
    # not a picture, copied beside every photo onto FAT/exFAT cards and network shares), .DS_Store, ...
    exts = image_extensions()
    return sorted(
        (p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in exts),
        key=lambda p: capture_key(p.name),
    )


HEIF_HINT = (
    "convert them to JPEG first (macOS: `sips -s format jpeg IMG.HEIC --out IMG.jpg`; Linux: "
    "`heif-convert IMG.HEIC IMG.jpg`; or set the iPhone to Settings > Camera > Formats > Most "
    "Compatible), or install pillow-heif so that sparself can read them"
)


def subfolders_with_images(folder: Path, max_depth: int = 3, limit: int = 5) -> list[tuple[str, int]]:
    """(relative sub-folder, image count) of the sub-folders holding images, e.g. a card's DCIM/100APPLE."""
    found = []
    exts = image_extensions()
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        depth = len(Path(root).relative_to(folder).parts)
        if depth >= max_depth:
            dirs[:] = []
        n = sum(1 for f in files if not f.startswith(".") and Path(f).suffix.lower() in exts)
        if n and depth:
            found.append((Path(root).relative_to(folder).as_posix(), n))
            if len(found) > limit:
                break
    return found


def list_images(folder: Path) -> list[Path]:
    """Image files of a folder in capture order (:func:`sparself.core.names.capture_key`: IMG_2 before
    IMG_10); hidden files (``._*``, ``.DS_Store``) are skipped, HEIC/HEIF
    photos are skipped with a warning saying how to convert them (read when pillow-heif is installed).
    Raises InputError if the folder is missing or has no images (naming sub-folders that hold some)."""
    folder = Path(folder)
    if not folder.exists():
        raise InputError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    files = image_files(folder)
    heif = (
        []
        if heif_readable()
        else sorted(
            p.name
            for p in folder.iterdir()
            if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in HEIF_EXTENSIONS
        )
    )
    if heif and files:
        log.warning(
            "%s: skipping %d HEIC/HEIF photo(s) (%s) that sparself cannot read; %s",
            folder,
            len(heif),
            some(heif),
            HEIF_HINT,
        )
    if files:
        return files
    if heif:
        raise InputError(
            f"{folder}: no images sparself can read: {len(heif)} HEIC/HEIF photo(s) ({some(heif)}); {HEIF_HINT}"
        )
    sub = subfolders_with_images(folder)
    if sub:
        named = ", ".join(f"{d} ({n} images)" for d, n in sub[:5]) + (", ..." if len(sub) > 5 else "")
        raise InputError(
            f"{folder}: no images in this folder itself, but in its sub-folder(s) {named}; "
            f"pass one of those folders, e.g. {folder / sub[0][0]}"
        )
    raise InputError(f"{folder}: no images found (looked for {', '.join(IMAGE_EXTENSIONS)})")


def some(names: Sequence[str], k: int = 5) -> str:
    """The first k names, and how many more."""
    return ", ".join(names[:k]) + (f" and {len(names) - k} more" if len(names) > k else "")


SIXTEEN_BIT = ("I;16", "I;16B", "I;16L", "I")


def conversion_of(path: Path) -> tuple[str | None, bool]:
    """(colour conversion or None, EXIF-rotated) of an image file, from its header only. The conversion is
    the PIL mode that :func:`load_image` turns into RGB ("L", "RGBA", "CMYK", "P", ...) or "16-bit"."""
    with Image.open(path) as im:
        return conversion(im)


def conversion(im: Image.Image) -> tuple[str | None, bool]:
    """:func:`conversion_of` an opened image (before ``exif_transpose``)."""
    rotated = int(im.getexif().get(0x0112, 1) or 1) not in (0, 1)
    return ("16-bit" if im.mode in SIXTEEN_BIT else None if im.mode == "RGB" else im.mode), rotated


def needs_conversion(path: Path) -> bool:
    """True when the file is not stored as upright RGB: its pixels as sparself sees them differ from its
    bytes as other tools read them (a copy must be converted, not copied)."""
    conv, rotated = conversion_of(path)
    return conv is not None or rotated


def note_conversions(paths: Sequence[Path]) -> None:
    """Log the conversions :func:`load_image` applies to these files: one line per folder and kind (a
    warning for colour conversions, information for EXIF rotation), with a count and the first names;
    a folder and kind said once per process, so that loading the same images again stays quiet."""
    kinds: dict[tuple[str, str], list[str]] = {}
    for p in paths:
        try:
            conv, rotated = conversion_of(p)
        except (OSError, SyntaxError, ValueError):
            continue  # unreadable files are reported by load_image itself
        folder = str(Path(p).parent)
        if conv is not None:
            kinds.setdefault((folder, conv), []).append(Path(p).name)
        if rotated:
            kinds.setdefault((folder, "EXIF"), []).append(Path(p).name)
    for (folder, kind), names in kinds.items():
        if (folder, kind) in _WARNED:
            continue
        _WARNED.add((folder, kind))
        if kind == "EXIF":
            log.info("%s: %d EXIF-rotated image(s) turned upright: %s", folder, len(names), some(names))
        else:
            what = {"L": "grayscale L", "LA": "grayscale LA", "P": "palette P", "I;16": "16-bit"}.get(kind, kind)
            why = " (alpha dropped)" if kind in ("RGBA", "LA", "PA") else ""
            log.warning("%s: %d %s image(s) converted to RGB%s: %s", folder, len(names), what, why, some(names))


def nonempty_file(path: Path, kind: str = "file") -> Path:
    """``path`` when it is a file with something in it; else InputError naming it."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such {kind}")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: {kind} is empty (0 bytes)")
    return path


def load_image(path: Path, size: tuple[int, int] | None = None, *, warn: bool = True) -> np.ndarray:
    """Decode an image file to (H, W, 3) float32 RGB in [0, 1].

    EXIF orientation is applied (phone photos), grayscale and RGBA are converted to RGB (alpha is
    dropped), 16-bit images keep their precision. size: optional (W, H) to resize to (area filter).
    Raises InputError naming the file when it is empty, truncated or not an image.
    """
    path = nonempty_file(path)
    try:
        with Image.open(path) as f:
            f.load()
            conv, rotated = conversion(f)
            im = ImageOps.exif_transpose(f)
            mode = im.mode
            if mode in SIXTEEN_BIT:
                arr = np.asarray(im, dtype=np.float32)
                arr = arr / (65535.0 if arr.max() > 255 or mode.startswith("I;16") else 255.0)
                arr = np.repeat(arr[..., None], 3, axis=2)
            else:
                arr = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
        if warn and (conv is not None or rotated):
            note_folder_once(path, conv, rotated)
    except UnidentifiedImageError:
        if path.suffix.lower() in HEIF_EXTENSIONS:
            raise InputError(f"{path}: HEIC/HEIF photo that sparself cannot read; {HEIF_HINT}") from None
        raise InputError(f"{path}: not an image file (cannot identify format)") from None
    except (OSError, SyntaxError, ValueError) as e:
        raise InputError(f"{path}: cannot decode image ({e}); the file may be truncated or corrupt") from None
    arr = np.ascontiguousarray(np.clip(arr, 0.0, 1.0), dtype=np.float32)
    if size is not None and (arr.shape[1], arr.shape[0]) != tuple(size):
        arr = resize_image(arr, size)
    return arr


def note_folder_once(path: Path, conv: str | None, rotated: bool) -> None:
    """A converted image: say what its folder's images need (once per folder and kind, with a count)."""
    folder = str(path.parent)
    todo = [k for k in (conv, "EXIF" if rotated else None) if k is not None and (folder, k) not in _WARNED]
    if not todo:
        return
    try:
        note_conversions(image_files(path.parent))
    except OSError:
        pass
    note_conversions([path])  # a file the folder listing skips (an odd suffix) is still said once


def read_mask(path: Path) -> np.ndarray:
    """A mask file (nerfstudio's ``mask_path``, sparself's ``masks/``) as (H, W) uint8, 0 = ignore, 255 =
    full weight; any 8-bit mode is read as its grey level. Raises InputError naming the file when it is
    missing, empty, not an image or not 8-bit."""
    path = nonempty_file(path, "mask file")
    try:
        with Image.open(path) as im:
            if im.mode in SIXTEEN_BIT or im.mode == "F":
                raise InputError(f"{path}: mask is a {im.mode} image; masks are 8-bit (0 ignore .. 255 full weight)")
            return np.asarray(im.convert("L"), dtype=np.uint8)
    except UnidentifiedImageError:
        raise InputError(f"{path}: mask is not an image file (cannot identify format)") from None
    except (OSError, SyntaxError, ValueError) as e:
        raise InputError(f"{path}: cannot decode mask ({e}); the file may be truncated or corrupt") from None


def image_size_of(path: Path) -> tuple[int, int]:
    """(W, H) of an image file after EXIF orientation, reading only its header."""
    if Path(path).is_file() and Path(path).stat().st_size == 0:
        raise InputError(f"{path}: file is empty (0 bytes)")
    try:
        with Image.open(path) as im:
            w, h = im.size
            orient = im.getexif().get(0x0112, 1)
    except UnidentifiedImageError:
        raise InputError(f"{path}: not an image file (cannot identify format)") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read image ({e})") from None
    return (h, w) if orient in (5, 6, 7, 8) else (w, h)


def resize_image(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize (H, W, 3) float32 to size = (W, H), area-averaging when shrinking."""
    import cv2

    w, h = int(size[0]), int(size[1])
    interp = cv2.INTER_AREA if w < img.shape[1] else cv2.INTER_LINEAR
    return np.ascontiguousarray(cv2.resize(img, (w, h), interpolation=interp), dtype=np.float32)


def resize_images(maps: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(T, H, W[, 3]) images or maps at size = (W, H) (:func:`resize_image` each; as they are at that size)."""
    if (maps.shape[2], maps.shape[1]) == tuple(size):
        return np.asarray(maps, np.float32)
    return np.stack([resize_image(np.asarray(m, np.float32), size) for m in maps])


def save_image(path: Path, img: np.ndarray) -> None:
    """Write (H, W, 3) float in [0, 1] as 8-bit PNG or JPEG (by suffix)."""
    arr = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    Image.fromarray(arr).save(path, quality=95) if Path(path).suffix.lower() in (".jpg", ".jpeg") else Image.fromarray(
        arr
    ).save(path)
