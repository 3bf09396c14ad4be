"""COLMAP models (text or binary) <-> :class:`Scene`, through pycolmap.

COLMAP's convention IS the internal one (world-to-camera, quaternion ``[qw, qx, qy, qz]``), so no axis
conversion happens here; only ordering (frames by image name = capture order) and camera de-duplication.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import Pose
from ..scene import Camera, Frame, Scene, image_size_of
from ._common import check_finite, find_image, scene_cameras_dedup

log = logging.getLogger(__name__)

_MODEL_FILES = ("cameras", "images", "points3D")


def find_model_dir(path: Path) -> Path | None:
    """The COLMAP model folder for ``path``: ``path`` itself (holding cameras.bin|txt), ``path/sparse/0``,
    or ``path/sparse``; None if there is none."""
    path = Path(path)
    for cand in (path, path / "sparse" / "0", path / "sparse"):
        if (cand / "cameras.bin").is_file() or (cand / "cameras.txt").is_file():
            return cand
    return None


def _default_image_dir(model_dir: Path) -> Path:
    # <scene>/sparse/0 -> <scene>/images ; <scene>/sparse -> <scene>/images ; <model> -> <model>/../images
    p = model_dir.resolve()
    if p.parent.name == "sparse":
        return p.parent.parent / "images"
    if p.name == "sparse":
        return p.parent / "images"
    return p.parent / "images"


def _check_model_files(model_dir: Path) -> None:
    for stem in _MODEL_FILES:
        b, t = model_dir / f"{stem}.bin", model_dir / f"{stem}.txt"
        if not (b.is_file() or t.is_file()):
            raise InputError(f"{model_dir}: COLMAP model is missing {stem}.bin / {stem}.txt")
        f = b if b.is_file() else t
        if f.stat().st_size == 0 and stem != "points3D":
            raise InputError(f"{f}: file is empty (0 bytes)")
        if f is t and stem in _TEXT_LAYOUT:
            _check_text_model(t, stem)


_TEXT_LAYOUT = {"cameras": "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]",
                "images": "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"}


def _check_text_model(path: Path, stem: str) -> None:
    """Readable errors for a malformed cameras.txt / images.txt (pycolmap reports C++ assertion text):
    each camera line and each image pose line must have its fields, as finite numbers."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({e})") from None
    k = 0
    while k < len(lines):
        fields = lines[k].split()
        k += 1
        if not fields or fields[0].startswith("#"):
            continue
        where = f"{path}: line {k}"
        if len(fields) < (5 if stem == "cameras" else 10):
            raise InputError(f"{where} has {len(fields)} fields, expected {_TEXT_LAYOUT[stem]}")
        nums = fields[:1] + fields[2:] if stem == "cameras" else fields[:9]
        try:
            vals = np.array([float(v) for v in nums])
        except ValueError:
            raise InputError(f"{where} has a non-numeric value (expected {_TEXT_LAYOUT[stem]})") from None
        check_finite(vals, where)
        if stem == "images":
            k += 1  # the next line lists the image's 2D points (possibly empty)


def load_reconstruction(model_dir: Path):
    """pycolmap.Reconstruction of a model folder; unreadable/truncated files -> InputError naming it."""
    import pycolmap

    model_dir = Path(model_dir)
    _check_model_files(model_dir)
    try:
        return pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises plain RuntimeError/ValueError on malformed files
        raise InputError(f"{model_dir}: cannot read COLMAP model ({str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__}); "
                         "a file may be truncated or corrupt") from None


def scene_from_reconstruction(rec, image_dir: Path | None, *, source: Path | None = None,
                              require_images: bool = True, check_sizes: bool = True) -> Scene:
    """Convert a pycolmap.Reconstruction to a Scene: registered images only, frames sorted by name,
    ``index`` 0..N-1, ``points`` from points3D (colours in ``meta['point_colors']``).

    image_dir: folder the image names are relative to (None: frames get no path).
    Images without a pose are listed in ``meta['unregistered']``.
    """
    where = source or image_dir or "COLMAP model"
    cams: dict[int, Camera] = {}
    for cid, c in sorted(rec.cameras.items()):
        model = c.model.name
        params = np.asarray(c.params, dtype=np.float64)
        check_finite(params, f"{where}: camera {cid} parameters")
        try:
            cams[int(cid)] = Camera(model, int(c.width), int(c.height), tuple(params))
        except ValueError as e:
            raise InputError(f"{where}: camera {cid}: {e}") from None
    frames, unregistered = [], []
    for img in sorted(rec.images.values(), key=lambda im: im.name):
        if not img.has_pose:
            unregistered.append(img.name)
            continue
        T = img.cam_from_world()
        x, y, z, w = np.asarray(T.rotation.quat, dtype=np.float64)
        q, t = np.array([w, x, y, z]), np.asarray(T.translation, dtype=np.float64)
        check_finite(np.concatenate([q, t]), f"{where}: pose of image {img.name}")
        path = None
        if image_dir is not None:
            path = find_image(Path(image_dir), img.name, required=require_images)
            cam = cams[int(img.camera_id)]
            if path is not None and check_sizes and image_size_of(path) != (cam.width, cam.height):
                w_, h_ = image_size_of(path)
                raise InputError(f"{path}: image is {w_}x{h_} but COLMAP camera {img.camera_id} "
                                 f"says {cam.width}x{cam.height}")
        frames.append(Frame(name=img.name, pose=Pose(q, t), camera_id=int(img.camera_id), path=path))
    for i, f in enumerate(frames):
        f.index = float(i)
    points, colors = None, None
    if rec.num_points3D():
        pts = [p for _, p in sorted(rec.points3D.items())]  # by id: stable order
        points = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
        colors = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
        keep = np.all(np.isfinite(points), axis=1)
        points, colors = points[keep], colors[keep]
    scene = Scene(cameras=cams, frames=frames, points=points, source=source,
                  meta={"format": "colmap", "unregistered": unregistered})
    if colors is not None:
        scene.meta["point_colors"] = colors
    return scene_cameras_dedup(scene)


def read_colmap(path: Path, images: Path | None = None, *, require_images: bool = True) -> Scene:
    """Read a COLMAP model folder (text or binary) and its images.

    path: a scene folder holding ``sparse/0`` (or ``sparse``), or the model folder itself.
    images: the images folder; default ``images/`` beside ``sparse/``.
    require_images: a registered image whose file is missing raises InputError (else its path is None).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    model_dir = find_model_dir(path if path.is_dir() else path.parent)
    if model_dir is None:
        raise InputError(f"{path}: no COLMAP model (cameras.bin/.txt) here or in sparse/0")
    image_dir = Path(images) if images is not None else _default_image_dir(model_dir)
    if require_images and not image_dir.is_dir():
        raise InputError(f"{image_dir}: images folder of COLMAP model {model_dir} not found")
    rec = load_reconstruction(model_dir)
    if rec.num_reg_images() == 0:
        raise InputError(f"{model_dir}: COLMAP model has no registered images")
    return scene_from_reconstruction(rec, image_dir if image_dir.is_dir() else None, source=model_dir,
                                     require_images=require_images)


def reconstruction_from_scene(scene: Scene):
    """A pycolmap.Reconstruction with the scene's cameras, frames (image ids 1..N in frame order) and
    points (without tracks: COLMAP, gsplat and nerfstudio read track-less points3D)."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    for cid, cam in sorted(scene.cameras.items()):
        rec.add_camera_with_trivial_rig(pycolmap.Camera(model=cam.model, width=cam.width, height=cam.height,
                                                        params=list(cam.params), camera_id=int(cid)))
    for i, f in enumerate(scene.frames):
        qw, qx, qy, qz = f.pose.qvec
        T = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([qx, qy, qz, qw])), f.pose.tvec.reshape(3, 1))
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f.name, camera_id=int(f.camera_id), image_id=i + 1), T)
    if scene.points is not None and len(scene.points):
        colors = scene.meta.get("point_colors")
        if colors is None or len(colors) != len(scene.points):
            colors = np.full((len(scene.points), 3), 128, dtype=np.uint8)
        for p, c in zip(np.asarray(scene.points, dtype=np.float64), np.asarray(colors, dtype=np.uint8)):
            rec.add_point3D(p, pycolmap.Track(), c)
    return rec


def write_colmap(scene: Scene, model_dir: Path, *, text: bool = False) -> Path:
    """Write the scene as a COLMAP model into ``model_dir`` (binary ``cameras/images/points3D.bin``;
    ``.txt`` instead when ``text``). Not atomic by itself: write into a folder from ``outputs.atomic_dir``."""
    model_dir = Path(model_dir)
    model_dir.mkdir(parents=True, exist_ok=True)
    rec = reconstruction_from_scene(scene)
    (rec.write_text if text else rec.write_binary)(str(model_dir))
    return model_dir
