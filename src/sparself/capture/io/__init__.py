"""Scene file formats: COLMAP model, LLFF ``poses_bounds.npy``, nerfstudio ``transforms.json``,
Middlebury ``*_par.txt``. Conversions between their conventions happen here and nowhere else; inside, every
pose is COLMAP world-to-camera.

``read_scene(path)`` autodetects the format; ``write_scene(scene, out_dir)`` writes one folder that
COLMAP, gsplat, nerfstudio and LLFF/NeRF loaders read unchanged::

    out_dir/images/<frame.name>          the frame images
    out_dir/sparse/0/cameras.bin ...     COLMAP binary model (cameras, images, points3D; + rigs, frames)
    out_dir/poses_bounds.npy             LLFF
    out_dir/transforms.json              nerfstudio (+ sparse_pc.ply when the scene has points)

A scene with synthesized frames (a dense scene) also gets, see :mod:`sparself.capture.io.dense`: names in an order
that keeps synthesized frames off every 8th position, ``train/val/test_list.txt`` (+ ``sparse/0/test.txt``),
split lists in ``transforms.json``, ``sparself.json``, and ``images_2/4/8`` copies.
"""

from __future__ import annotations

import logging
import os
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Sequence

from sparself.capture.images import image_size_of, needs_conversion, save_image
from sparself.capture.io import dense as _dense
from sparself.capture.io.colmap import find_model_dir, read_colmap, write_colmap
from sparself.capture.io.dense import DenseInfo
from sparself.capture.io.dense_photos import DensePhotos, dense_photos
from sparself.capture.io.llff import read_llff, write_llff
from sparself.capture.io.middlebury import find_par_file, read_middlebury, write_middlebury
from sparself.capture.io.nerfstudio import read_nerfstudio, write_nerfstudio
from sparself.capture.scene import Frame, Scene, undistorted
from sparself.core.errors import InputError
from sparself.core.names import check_names
from sparself.core.outputs import atomic_dir, scene_inputs, write_marker

__all__ = [
    "DenseInfo",
    "DensePhotos",
    "read_dense_photos",
    "read_scene",
    "write_scene",
    "write_scene_into",
    "detect_format",
    "read_colmap",
    "write_colmap",
    "read_llff",
    "write_llff",
    "read_nerfstudio",
    "write_nerfstudio",
    "read_middlebury",
    "write_middlebury",
    "FORMATS",
]

log = logging.getLogger(__name__)

FORMATS = ("colmap", "llff", "nerfstudio")


def detect_format(path: Path) -> str:
    """'colmap' | 'llff' | 'nerfstudio' | 'middlebury' for a scene folder or pose file; InputError if none.

    A folder holding several (as written by :func:`write_scene`) is read as COLMAP, which keeps the most
    (full intrinsics and sparse points)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    if path.is_file():
        name = path.name
        if name.endswith("_par.txt"):
            return "middlebury"
        if name.endswith(".npy"):
            return "llff"
        if name.endswith(".json"):
            return "nerfstudio"
        if path.stem in ("cameras", "images", "points3D") and path.suffix in (".bin", ".txt"):
            return "colmap"
        raise InputError(
            f"{path}: unknown pose file type (expected *_par.txt, poses_bounds.npy, "
            "transforms.json or a COLMAP cameras/images/points3D file)"
        )
    if find_model_dir(path) is not None:
        return "colmap"
    if (path / "poses_bounds.npy").is_file():
        return "llff"
    if (path / "transforms.json").is_file():
        return "nerfstudio"
    if find_par_file(path) is not None:
        return "middlebury"
    raise InputError(
        f"{path}: no scene found (looked for sparse/0 or cameras.bin|txt, poses_bounds.npy, "
        "transforms.json, *_par.txt); to recover poses from photos run `sparself poses`"
    )


def read_scene(path: Path, images: Path | None = None) -> Scene:
    """Read a scene in any supported format (see :func:`detect_format`).

    images: images folder, for COLMAP and LLFF (default ``images/`` beside the model / pose file).
    Frames come sorted by image name with ``index`` 0..N-1. A dense scene's masks (transforms.json's
    ``mask_path``; ``masks/`` beside ``images/`` for COLMAP and LLFF) come back as the frames' ``mask``,
    which :meth:`Scene.pixel_weight` reads as confidence. Cameras with lens distortion come back as pinhole
    cameras whose photos are undistorted when loaded (:func:`~sparself.capture.scene.undistorted`).
    """
    path = Path(path)
    fmt = detect_format(path)
    if fmt == "colmap":
        scene = read_colmap(path.parent if path.is_file() else path, images)
    elif fmt == "llff":
        scene = read_llff(path, images)
    elif fmt == "nerfstudio":
        scene = read_nerfstudio(path)
    else:
        return read_middlebury(path)
    scene = undistorted(scene)
    synthetic = _dense.read_synthetic_names(_scene_folder(path))
    return _dense.mark_synthetic(scene, synthetic) if synthetic else scene


def read_dense_photos(scene: Scene, path: Path) -> DensePhotos | None:
    """The photos of ``scene``, read from ``path``, as the capture they came from when it is a dense scene
    sparself wrote (:func:`sparself.capture.io.dense_photos.dense_photos`); None otherwise."""
    return dense_photos(scene, _scene_folder(Path(path)))


def _scene_folder(path: Path) -> Path:
    """The folder a dense scene's ``sparself.json`` would be in, for a path given to :func:`read_scene`."""
    folder = path if path.is_dir() else path.parent
    if folder.name == "0" and folder.parent.name == "sparse":
        return folder.parent.parent
    return folder.parent if folder.name == "sparse" else folder


def _same_format(a: Path, b: Path) -> bool:
    jpeg = (".jpg", ".jpeg")
    sa, sb = Path(a).suffix.lower(), Path(b).suffix.lower()
    return sa == sb or (sa in jpeg and sb in jpeg)


def _write_image(frame: Frame, scene: Scene, i: int, dst: Path, link: bool) -> None:
    cam = scene.camera(i)
    dst.parent.mkdir(parents=True, exist_ok=True)
    if (
        frame.image is None
        and frame.path is not None
        and image_size_of(frame.path) == (cam.width, cam.height)
        and _same_format(frame.path, dst)
        and not needs_conversion(frame.path)
        and frame.camera_id not in scene.undistort
    ):
        if link:
            os.symlink(Path(frame.path).resolve(), dst)
        else:
            shutil.copyfile(frame.path, dst)  # original bytes: no re-encoding loss
        return
    if frame.image is None and frame.path is None:
        raise InputError(f"frame {frame.name} has no image to write (a planned pose that was not synthesized)")
    save_image(dst, scene.load(i))  # resized to its camera when the scene was resized; upright 8-bit RGB


def write_scene_into(
    scene: Scene,
    folder: Path,
    formats: Sequence[str] = FORMATS,
    *,
    images: str = "copy",
    text: bool = False,
    dense: DenseInfo | None = None,
) -> Scene:
    """Write the scene into an existing folder (NOT atomic: the caller gives an ``outputs.atomic_dir``).

    images: "copy" (original bytes when the size matches, else re-encoded at the camera size),
            "link" (symlinks to the originals where possible), or "none" (poses only).
    text: also write the COLMAP model as ``.txt`` files beside the ``.bin`` ones in ``sparse/0``.
    dense: provenance, user hold-out and options of a scene with synthesized frames (default
           :class:`DenseInfo`); such a scene is renamed and ordered by :func:`sparself.capture.io.dense.layout`.
    -> the scene as written (frame paths pointing into ``folder/images``).
    """
    folder = Path(folder)
    unknown = set(formats) - set(FORMATS) - {"middlebury"}
    if unknown:
        raise InputError(f"unknown output format(s) {sorted(unknown)}; choose from {FORMATS + ('middlebury',)}")
    if images not in ("copy", "link", "none"):
        raise ValueError(f"images must be 'copy', 'link' or 'none', got {images!r}")
    check_names([f.name for f in scene.frames], scene.source or "scene", what="frame name", subfolders=True)
    split, dense = None, dense or DenseInfo()
    sources: list[str] = []
    if any(f.synthetic for f in scene.frames) or dense.selfcheck is not None:
        scene, split, sources = _dense.layout(scene, dense)
    new_frames = []
    for i, f in enumerate(scene.frames):
        dst = folder / "images" / f.name
        if images != "none":
            _write_image(f, scene, i, dst, link=images == "link")
        new_frames.append(
            replace(f, path=dst if images != "none" else f.path, image=None if images != "none" else f.image)
        )
    write_marker(folder)
    written = replace(scene, frames=new_frames, source=folder, observations=dict(scene.observations))
    masks = images != "none" and any(f.confidence is not None or f.mask is not None for f in scene.frames)
    if masks:  # synthesized views' confidence (nerfstudio's mask_path), or the masks a scene was read with
        _dense.write_masks(folder, written, _dense.FACTORS if dense.downscale else ())
    _write_formats(written, folder, formats, text, split, masks)
    if split is not None:
        _dense.write_split_files(folder, split)
        _dense.write_sparself_json(folder, written, split, sources, dense)
        if dense.downscale and images != "none":
            _dense.write_downscaled(folder, written)
    return written


def _write_formats(scene: Scene, folder: Path, formats: Sequence[str], text: bool, split, masks: bool = False) -> None:
    if "colmap" in formats:
        write_colmap(scene, folder / "sparse" / "0")
        if text:
            write_colmap(scene, folder / "sparse" / "0", text=True)
    if "llff" in formats:
        write_llff(scene, folder)
    if "nerfstudio" in formats:
        write_nerfstudio(scene, folder, split=split, masks=masks)
    if "middlebury" in formats:
        write_middlebury(scene, folder / "scene_par.txt")


def write_scene(
    scene: Scene,
    out_dir: Path,
    formats: Sequence[str] = FORMATS,
    *,
    overwrite: bool = False,
    images: str = "copy",
    text: bool = False,
    dense: DenseInfo | None = None,
) -> Scene:
    """Write ``images/`` + ``sparse/0/`` + ``poses_bounds.npy`` + ``transforms.json`` to ``out_dir``,
    atomically (a temporary sibling renamed at the end, via ``outputs.atomic_dir``: a failure leaves
    nothing). An existing non-empty ``out_dir`` is refused unless ``overwrite``.
    -> the scene as written (frame paths into ``out_dir/images``)."""
    out_dir = Path(out_dir)
    with atomic_dir(out_dir, overwrite, scene_inputs(scene)) as tmp:  # never over the scene's own files
        written = write_scene_into(scene, tmp, formats, images=images, text=text, dense=dense)
    # paths were into the temporary folder, which is now out_dir
    for f in written.frames:
        if f.path is not None and Path(f.path).is_relative_to(tmp):
            f.path = out_dir / Path(f.path).relative_to(tmp)
    written.source = out_dir
    return written
