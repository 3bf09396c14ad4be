"""Scene, Camera, Frame: a capture's images, intrinsics and poses in ONE convention (COLMAP world-to-camera).

Image decoding lives here, once: EXIF orientation is applied, grayscale / RGBA / 16-bit images become
RGB float32 in [0, 1], and any unreadable file raises :class:`InputError` naming it.
"""

from __future__ import annotations

import functools
import logging
import os
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from .errors import InputError
from .geometry import Pose, fov_deg, intrinsics_matrix

log = logging.getLogger(__name__)

# fewer sparse points than this are not used: 3DGS starts from random points instead, and triangulation that
# finds fewer leaves a scene without points
MIN_POINTS = 100

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")

# Parameter layouts of the COLMAP camera models we read: (fx, fy, cx, cy) are taken from these.
_PINHOLE_LIKE = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "SIMPLE_RADIAL_FISHEYE": ("f", "cx", "cy", "k"),
    "RADIAL_FISHEYE": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}


@dataclass(frozen=True)
class Camera:
    """Intrinsics of one physical camera, with COLMAP's model name and parameter order.

    Distortion parameters are carried through for export but ignored by the pinhole maths here.
    """

    model: str
    width: int
    height: int
    params: tuple[float, ...]

    def __post_init__(self) -> None:
        if self.model not in _PINHOLE_LIKE:
            raise ValueError(f"unsupported camera model {self.model!r}")
        names = _PINHOLE_LIKE[self.model]
        if len(self.params) != len(names):
            raise ValueError(f"{self.model} needs {len(names)} parameters, got {len(self.params)}")
        if not np.all(np.isfinite(self.params)):
            raise ValueError("camera parameters contain NaN or inf")
        object.__setattr__(self, "params", tuple(float(p) for p in self.params))

    def _get(self, name: str) -> float:
        return self.params[_PINHOLE_LIKE[self.model].index(name)]

    @property
    def fx(self) -> float:
        return self._get("f") if "f" in _PINHOLE_LIKE[self.model] else self._get("fx")

    @property
    def fy(self) -> float:
        return self._get("f") if "f" in _PINHOLE_LIKE[self.model] else self._get("fy")

    @property
    def cx(self) -> float:
        return self._get("cx")

    @property
    def cy(self) -> float:
        return self._get("cy")

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsics matrix."""
        return intrinsics_matrix(self.fx, self.fy, self.cx, self.cy)

    @property
    def fov_deg(self) -> tuple[float, float]:
        """(horizontal, vertical) field of view in degrees."""
        return fov_deg(self.width, self.fx), fov_deg(self.height, self.fy)

    @classmethod
    def pinhole(cls, width: int, height: int, fx: float, fy: float | None = None,
                cx: float | None = None, cy: float | None = None) -> "Camera":
        """A PINHOLE camera; the principal point defaults to the image centre."""
        fy = fx if fy is None else fy
        cx = width / 2.0 if cx is None else cx
        cy = height / 2.0 if cy is None else cy
        return cls("PINHOLE", int(width), int(height), (fx, fy, cx, cy))

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for images resampled to (width, height): focal and centre scale per axis.

        Follows the pixel-corner convention (COLMAP's): a pixel centre x maps to (x + 0.5) s - 0.5
        only approximately; we scale the principal point by s, as COLMAP's own image undistorter does.
        """
        sx, sy = width / self.width, height / self.height
        return Camera.pinhole(width, height, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy)


@dataclass
class Frame:
    """One image of a scene: its pose, its camera, its place in the capture order.

    index: position in capture order; fractional for planned (novel) poses, e.g. 3.5 between 3 and 4.
    path: the image file, or None for a pose without a photo (a planned view before synthesis).
    image: an in-memory image (H, W, 3) float32 in [0, 1], used instead of ``path`` when set
           (synthesized views before they are written).
    confidence: a synthesized view's per-pixel confidence (H, W) in [0, 1], written as ``masks/``.
    mask: a mask file holding the confidence (8-bit, value / 255: nerfstudio's ``mask_path``, sparself's
          ``masks/``), as read back from a scene; decoded only when used (:meth:`Scene.confidence_map`),
          so that a megapixel scene does not hold every map in memory. ``confidence`` wins when both are set.
    weight: the frame's loss weight in the in-project reconstructors (in memory only; the evaluation sets it on
            synthesized frames): each pixel counts ``weight`` x its confidence (see :meth:`Scene.pixel_weight`).
    """

    name: str
    pose: Pose
    camera_id: int = 1
    index: float = 0.0
    path: Path | None = None
    image: np.ndarray | None = None
    synthetic: bool = False
    confidence: np.ndarray | None = None
    mask: Path | None = None
    weight: float = 1.0


@dataclass
class Scene:
    """A capture: cameras (by id), frames in capture order, optional depth bounds and sparse points.

    bounds: (near, far) scene depth range over all cameras, if known (LLFF stores it; COLMAP points give it).
    points: (P, 3) sparse world points, if known.
    """

    cameras: dict[int, Camera]
    frames: list[Frame]
    bounds: tuple[float, float] | None = None
    points: np.ndarray | None = None
    source: Path | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for f in self.frames:
            if f.camera_id not in self.cameras:
                raise ValueError(f"frame {f.name} refers to unknown camera {f.camera_id}")

    def __len__(self) -> int:
        return len(self.frames)

    # ---- poses -------------------------------------------------------------------------------
    @property
    def poses(self) -> list[Pose]:
        return [f.pose for f in self.frames]

    def camera(self, i: int) -> Camera:
        """The camera of frame i."""
        return self.cameras[self.frames[i].camera_id]

    def centers(self) -> np.ndarray:
        """(N, 3) camera centres."""
        return np.stack([f.pose.center for f in self.frames]) if self.frames else np.zeros((0, 3))

    def c2w(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world matrices (OpenCV camera axes)."""
        return np.stack([f.pose.c2w() for f in self.frames])

    def w2c(self) -> np.ndarray:
        """(N, 4, 4) world-to-camera matrices."""
        return np.stack([f.pose.w2c() for f in self.frames])

    def scale(self) -> float:
        """A length scale of the capture: the median distance of camera centres to their mean (>0)."""
        c = self.centers()
        d = np.linalg.norm(c - c.mean(0), axis=1)
        s = float(np.median(d)) if len(d) else 1.0
        return s if s > 1e-9 else 1.0

    def depth_bounds(self) -> tuple[float, float]:
        """(near, far) scene depth. From ``bounds`` if known, else from the sparse points seen in front
        of the cameras (1st/99th percentile), else a guess from the camera layout (logged)."""
        if self.bounds is not None:
            return float(self.bounds[0]), float(self.bounds[1])
        if self.points is not None and len(self.points) >= 10:
            depths = []
            for f in self.frames:
                z = (self.points @ f.pose.R.T + f.pose.tvec)[:, 2]
                depths.append(z[z > 0])
            z = np.concatenate(depths) if depths else np.zeros(0)
            if len(z) >= 10:
                near, far = np.percentile(z, 1) * 0.9, np.percentile(z, 99) * 1.1
                return float(max(near, 1e-3)), float(max(far, near * 1.5))
        # Cameras looking at a common centre: the scene lies around the centroid of the centres.
        dist = float(np.median(np.linalg.norm(self.centers() - self.centers().mean(0), axis=1)))
        dist = dist if dist > 1e-9 else 1.0
        log.warning("scene has no depth bounds or sparse points; guessing near/far from camera layout")
        return 0.2 * dist, 5.0 * dist

    # ---- images ------------------------------------------------------------------------------
    def image(self, i: int, size: tuple[int, int] | None = None) -> np.ndarray:
        """Image of frame i as (H, W, 3) float32 in [0, 1], optionally resized to size = (W, H)."""
        f = self.frames[i]
        if f.image is not None:
            img = f.image
            if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
                img = resize_image(img, size)
            return img
        if f.path is None:
            raise InputError(f"frame {f.name} has no image (a planned pose that was not synthesized)")
        cam = self.camera(i)
        img = load_image(f.path, size=size)
        if size is None and (img.shape[1], img.shape[0]) != (cam.width, cam.height):
            raise InputError(
                f"{f.path}: image is {img.shape[1]}x{img.shape[0]} but its camera says {cam.width}x{cam.height}"
            )
        return img

    def images(self, size: tuple[int, int] | None = None, indices: Iterable[int] | None = None) -> np.ndarray:
        """(N, H, W, 3) float32 images (all frames, or ``indices``), optionally resized to size = (W, H)."""
        idx = range(len(self.frames)) if indices is None else list(indices)
        return np.stack([self.image(i, size) for i in idx])

    # ---- derived scenes ----------------------------------------------------------------------
    def subset(self, indices: Sequence[int]) -> "Scene":
        """A scene with only the given frames (in the given order); cameras and bounds are shared."""
        frames = [self.frames[i] for i in indices]
        return replace(self, frames=frames)

    def without(self, positions: Sequence[int]) -> "Scene":
        """The scene minus the frames at ``positions`` (a hold-out), the others in their order."""
        drop = set(positions)
        return self.subset([i for i in range(len(self)) if i not in drop])

    def resized(self, max_side: int) -> "Scene":
        """The scene at a lower resolution: cameras scaled so their longer side is ``max_side`` pixels.

        Images are resized when loaded through :meth:`image` with :meth:`image_size`.
        """
        cams = {}
        for cid, cam in self.cameras.items():
            s = max_side / max(cam.width, cam.height)
            w, h = max(1, int(round(cam.width * s))), max(1, int(round(cam.height * s)))
            cams[cid] = cam.resized(w, h)
        out = replace(self, cameras=cams)
        out.meta = dict(self.meta, resized_from={cid: (c.width, c.height) for cid, c in self.cameras.items()})
        return out

    def image_size(self, i: int = 0) -> tuple[int, int]:
        """(W, H) of frame i's camera."""
        c = self.camera(i)
        return c.width, c.height

    def load(self, i: int) -> np.ndarray:
        """Image of frame i at its camera's size (resizing when the scene was :meth:`resized`)."""
        return self.image(i, self.image_size(i))

    def confidence_map(self, i: int) -> np.ndarray | None:
        """Frame i's confidence (H, W) float32 at the size it was made or stored at: its in-memory
        ``confidence``, else its ``mask`` file (value / 255, :func:`read_mask`), else None (no map)."""
        f = self.frames[i]
        if f.confidence is not None:
            return np.asarray(f.confidence, np.float32)
        return None if f.mask is None else np.divide(read_mask(f.mask), 255.0, dtype=np.float32)

    def pixel_weight(self, i: int) -> np.ndarray | None:
        """Frame i's per-pixel loss weight (H, W) at its camera's size: its ``weight`` x its confidence map
        (:meth:`confidence_map`); None when every pixel counts 1 (weight 1, no map), so reconstructors keep
        their plain loss."""
        f = self.frames[i]
        if f.confidence is None and f.mask is None and f.weight == 1.0:
            return None
        w, h = self.image_size(i)
        conf = self.confidence_map(i)
        if conf is None:
            return np.full((h, w), f.weight, np.float32)
        if f.confidence is not None:  # a map made in memory may hold NaN or go past [0, 1]; a mask's cannot
            conf = np.clip(np.nan_to_num(conf), 0.0, 1.0)
        if conf.shape != (h, w):
            conf = np.clip(resize_image(conf, (w, h)), 0.0, 1.0)
        return (f.weight * conf).astype(np.float32, copy=False)

    def load_all(self) -> np.ndarray:
        """(N, H, W, 3) images at the cameras' size. All frames must share one image size."""
        sizes = {self.image_size(i) for i in range(len(self))}
        if len(sizes) > 1:
            raise InputError(f"frames have different image sizes {sorted(sizes)}; resize the scene first")
        return np.stack([self.load(i) for i in range(len(self))])


# ---- image files -------------------------------------------------------------------------------

HEIF_EXTENSIONS = (".heic", ".heif")


@functools.cache
def _heif_readable() -> bool:
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
    return IMAGE_EXTENSIONS + (HEIF_EXTENSIONS if _heif_readable() else ())


def _image_files(folder: Path) -> list[Path]:
    # names starting with "." are hidden files: macOS AppleDouble "._IMG_0001.JPG" (resource-fork metadata,
    # not a picture, copied beside every photo onto FAT/exFAT cards and network shares), .DS_Store, ...
    exts = image_extensions()
    return sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".")
                  and p.suffix.lower() in exts)


HEIF_HINT = ("convert them to JPEG first (macOS: `sips -s format jpeg IMG.HEIC --out IMG.jpg`; Linux: "
             "`heif-convert IMG.HEIC IMG.jpg`; or set the iPhone to Settings > Camera > Formats > Most "
             "Compatible), or install pillow-heif so that sparself can read them")


def _subfolders_with_images(folder: Path, max_depth: int = 3, limit: int = 5) -> list[tuple[str, int]]:
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
    """Image files of a folder, sorted by name; hidden files (``._*``, ``.DS_Store``) are skipped, HEIC/HEIF
    photos are skipped with a warning saying how to convert them (read when pillow-heif is installed).
    Raises InputError if the folder is missing or has no images (naming sub-folders that hold some)."""
    folder = Path(folder)
    if not folder.exists():
        raise InputError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    files = _image_files(folder)
    heif = [] if _heif_readable() else sorted(p.name for p in folder.iterdir() if p.is_file()
                                               and not p.name.startswith(".") and p.suffix.lower() in HEIF_EXTENSIONS)
    if heif and files:
        log.warning("%s: skipping %d HEIC/HEIF photo(s) (%s) that sparself cannot read; %s", folder, len(heif),
                    _some(heif), HEIF_HINT)
    if files:
        return files
    if heif:
        raise InputError(f"{folder}: no images sparself can read: {len(heif)} HEIC/HEIF photo(s) ({_some(heif)}); "
                         f"{HEIF_HINT}")
    sub = _subfolders_with_images(folder)
    if sub:
        named = ", ".join(f"{d} ({n} images)" for d, n in sub[:5]) + (", ..." if len(sub) > 5 else "")
        raise InputError(f"{folder}: no images in this folder itself, but in its sub-folder(s) {named}; "
                         f"pass one of those folders, e.g. {folder / sub[0][0]}")
    raise InputError(f"{folder}: no images found (looked for {', '.join(IMAGE_EXTENSIONS)})")


def _some(names: Sequence[str], k: int = 5) -> str:
    """The first k names, and how many more."""
    return ", ".join(names[:k]) + (f" and {len(names) - k} more" if len(names) > k else "")


# ---- conversions to upright 8/32-bit RGB: what they are, said once per folder with a count ----------------

_SIXTEEN_BIT = ("I;16", "I;16B", "I;16L", "I")


def conversion_of(path: Path) -> tuple[str | None, bool]:
    """(colour conversion or None, EXIF-rotated) of an image file, from its header only. The conversion is
    the PIL mode that :func:`load_image` turns into RGB ("L", "RGBA", "CMYK", "P", ...) or "16-bit"."""
    with Image.open(path) as im:
        return _conversion(im)


def _conversion(im: Image.Image) -> tuple[str | None, bool]:
    """:func:`conversion_of` an opened image (before ``exif_transpose``)."""
    rotated = int(im.getexif().get(0x0112, 1) or 1) not in (0, 1)
    return ("16-bit" if im.mode in _SIXTEEN_BIT else None if im.mode == "RGB" else im.mode), rotated


def needs_conversion(path: Path) -> bool:
    """True when the file is not stored as upright RGB: its pixels as sparself sees them differ from its
    bytes as other tools read them (a copy must be converted, not copied)."""
    conv, rotated = conversion_of(path)
    return conv is not None or rotated


_WARNED: set[tuple[str, str]] = set()


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
            log.info("%s: %d EXIF-rotated image(s) turned upright: %s", folder, len(names), _some(names))
        else:
            what = {"L": "grayscale L", "LA": "grayscale LA", "P": "palette P", "I;16": "16-bit"}.get(kind, kind)
            why = " (alpha dropped)" if kind in ("RGBA", "LA", "PA") else ""
            log.warning("%s: %d %s image(s) converted to RGB%s: %s", folder, len(names), what, why, _some(names))


def _nonempty_file(path: Path, kind: str = "file") -> Path:
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
    path = _nonempty_file(path)
    try:
        with Image.open(path) as im:
            im.load()
            conv, rotated = _conversion(im)
            im = ImageOps.exif_transpose(im)
            mode = im.mode
            if mode in _SIXTEEN_BIT:
                arr = np.asarray(im, dtype=np.float32)
                arr = arr / (65535.0 if arr.max() > 255 or mode.startswith("I;16") else 255.0)
                arr = np.repeat(arr[..., None], 3, axis=2)
            else:
                arr = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
        if warn and (conv is not None or rotated):
            _note_folder_once(path, conv, rotated)
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


def _note_folder_once(path: Path, conv: str | None, rotated: bool) -> None:
    """A converted image: say what its folder's images need (once per folder and kind, with a count)."""
    folder = str(path.parent)
    todo = [k for k in (conv, "EXIF" if rotated else None) if k is not None and (folder, k) not in _WARNED]
    if not todo:
        return
    try:
        note_conversions(_image_files(path.parent))
    except OSError:
        pass
    note_conversions([path])  # a file the folder listing skips (an odd suffix) is still said once


def read_mask(path: Path) -> np.ndarray:
    """A mask file (nerfstudio's ``mask_path``, sparself's ``masks/``) as (H, W) uint8, 0 = ignore, 255 =
    full weight; any 8-bit mode is read as its grey level. Raises InputError naming the file when it is
    missing, empty, not an image or not 8-bit."""
    path = _nonempty_file(path, "mask file")
    try:
        with Image.open(path) as im:
            if im.mode in _SIXTEEN_BIT or im.mode == "F":
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


def save_image(path: Path, img: np.ndarray) -> None:
    """Write (H, W, 3) float in [0, 1] as 8-bit PNG or JPEG (by suffix)."""
    arr = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    Image.fromarray(arr).save(path, quality=95) if Path(path).suffix.lower() in (".jpg", ".jpeg") else \
        Image.fromarray(arr).save(path)


def one_size(scene: Scene) -> Scene:
    """Mixed image sizes: the scene with every camera resized to the most common size (with a warning),
    so that training and synthesis see one image size; different aspect ratios are refused (InputError)."""
    sizes = {(c.width, c.height) for c in scene.cameras.values()}
    if len(sizes) <= 1:
        return scene
    counts = Counter(scene.image_size(i) for i in range(len(scene)))
    w, h = max(sizes, key=lambda s: (counts.get(s, 0), s))
    if any(abs(cw * h - ch * w) > 0.01 * ch * w for cw, ch in sizes):
        raise InputError(f"{scene.source or 'scene'}: views have different aspect ratios "
                         f"({', '.join(f'{a}x{b}' for a, b in sorted(sizes))}); use photos of one shape")
    log.warning("%s: views have different image sizes (%s); resizing them to %dx%d", scene.source or "scene",
                ", ".join(f"{a}x{b}" for a, b in sorted(sizes)), w, h)
    return replace(scene, cameras={cid: c if (c.width, c.height) == (w, h) else c.resized(w, h)
                                   for cid, c in scene.cameras.items()})


def preloaded(scene: Scene) -> Scene:
    """The scene with every frame's image decoded at its camera's size and held in memory (so a resized
    scene writes resized images, and every consumer sees the same pixels)."""
    return replace(scene, frames=[replace(f, image=scene.load(i)) for i, f in enumerate(scene.frames)])
