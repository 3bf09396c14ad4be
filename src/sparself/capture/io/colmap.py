"""COLMAP models (text or binary) <-> :class:`Scene`, through pycolmap.

COLMAP's convention IS the internal one (world-to-camera, quaternion ``[qw, qx, qy, qz]``), so no axis
conversion happens here; only ordering (frames by image name = capture order) and camera de-duplication.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from sparself.capture.images import image_size_of
from sparself.capture.io._common import check_finite, find_image, scene_cameras_dedup
from sparself.capture.io.dense import read_masks_beside
from sparself.capture.scene import Camera, Frame, Observations, Scene
from sparself.core.errors import InputError
from sparself.core.geometry import Pose
from sparself.core.interrupts import import_native
from sparself.core.names import capture_key, check_names

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
    camera_ids: set[int] | None = None
    for stem in _MODEL_FILES:
        b, t = model_dir / f"{stem}.bin", model_dir / f"{stem}.txt"
        if not (b.is_file() or t.is_file()):
            raise InputError(f"{model_dir}: COLMAP model is missing {stem}.bin / {stem}.txt")
        f = b if b.is_file() else t
        if f.stat().st_size == 0 and stem != "points3D":
            raise InputError(f"{f}: file is empty (0 bytes)")
        if stem in _TEXT_LAYOUT:
            ids = _check_text_model(t, stem, camera_ids) if f is t else _check_binary_model(b, stem, camera_ids)
            camera_ids = ids if stem == "cameras" else camera_ids


_TEXT_LAYOUT = {
    "cameras": "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]",
    "images": "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME",
}


def _check_text_model(path: Path, stem: str, camera_ids: set[int] | None = None) -> set[int]:
    """Readable errors for a malformed cameras.txt / images.txt (pycolmap reports C++ assertion text, or
    reads a zero quaternion as the identity): each camera line and each image pose line must have its
    fields, as finite numbers; a pose needs a non-zero quaternion and a camera listed in cameras.txt
    (``camera_ids``, when known). Returns the ids of the lines' first field."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({e})") from None
    ids, k = set(), 0
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
        ids.add(int(vals[0]))
        if stem == "images":
            _check_image_line(where, vals, fields[9], camera_ids, path.parent / "cameras.txt")
            k += 1  # the next line lists the image's 2D points (possibly empty)
    return ids


def _check_image_line(where: str, vals: np.ndarray, name: str, camera_ids: set[int] | None, cameras_file: Path) -> None:
    if np.linalg.norm(vals[1:5]) < 1e-12:
        raise InputError(
            f"{where} ({name}): quaternion QW QX QY QZ is zero, which is no rotation (identity is 1 0 0 0)"
        )
    cam = int(vals[8])
    if camera_ids is not None and cam not in camera_ids:
        raise InputError(
            f"{where} ({name}): camera {cam} is not in {cameras_file} "
            f"(it lists {', '.join(map(str, sorted(camera_ids))) or 'none'})"
        )


# COLMAP camera model id -> number of parameters (colmap/sensor/models.h)
_NUM_PARAMS = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12, 11: 16}


def _check_binary_model(path: Path, stem: str, camera_ids: set[int] | None) -> set[int] | None:
    """What :func:`_check_text_model` checks, in cameras.bin / images.bin: a zero quaternion (pycolmap
    reads it as the identity) and an image whose camera is missing ("Rig with ID 7 does not exist").
    Returns the ids read, or None for a layout it does not know (pycolmap then has the last word)."""
    import struct

    ids: set[int] = set()
    try:
        with open(path, "rb") as f:
            (n,) = struct.unpack("<Q", f.read(8))
            for _ in range(n):
                if stem == "cameras":
                    cid, model, _w, _h = struct.unpack("<iiQQ", f.read(24))
                    if model not in _NUM_PARAMS:
                        return None
                    f.seek(8 * _NUM_PARAMS[model], 1)
                    ids.add(cid)
                    continue
                iid, qw, qx, qy, qz, _tx, _ty, _tz, cid = struct.unpack("<I7dI", f.read(64))
                name = b"".join(iter(lambda: f.read(1), b"\0")).decode("utf-8", "replace")
                (npts,) = struct.unpack("<Q", f.read(8))
                f.seek(24 * npts, 1)
                vals = np.array([iid, qw, qx, qy, qz, 0, 0, 0, cid], dtype=np.float64)
                _check_image_line(f"{path}: image {iid}", vals, name, camera_ids, path.parent / "cameras.bin")
                ids.add(iid)
    except struct.error:
        return None  # truncated: pycolmap's message names the file
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    return ids


def load_reconstruction(model_dir: Path):
    """pycolmap.Reconstruction of a model folder; unreadable/truncated files -> InputError naming it."""
    pycolmap = import_native("pycolmap")

    model_dir = Path(model_dir)
    _check_model_files(model_dir)
    _check_unique_ids(model_dir / "images.txt", image_lines=True)  # pycolmap would stop on a failed C++ check
    _check_unique_ids(model_dir / "cameras.txt")
    try:
        return pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises plain RuntimeError/ValueError on malformed files
        raise InputError(
            f"{model_dir}: cannot read COLMAP model "
            f"({str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__}); "
            "a file may be truncated or corrupt"
        ) from None


def _check_unique_ids(path: Path, image_lines: bool = False) -> None:
    """Refuse a text model file that gives one id (its first field) to two entries. In ``images.txt`` each
    image takes two lines, the second (its 2D points, maybe empty) read as it is, as COLMAP reads it."""
    if not path.is_file():
        return
    seen: dict[str, int] = {}
    lines = iter(enumerate(path.read_text(errors="replace").splitlines(), 1))
    for no, line in lines:
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if image_lines:
            next(lines, None)
        key = line.split()[0]
        if key in seen:
            what = "IMAGE_ID" if image_lines else "CAMERA_ID"
            raise InputError(f"{path}: line {no}: {what} {key} is already used on line {seen[key]}; ids must be unique")
        seen[key] = no


def scene_from_reconstruction(
    rec, image_dir: Path | None, *, source: Path | None = None, require_images: bool = True, check_sizes: bool = True
) -> Scene:
    """Convert a pycolmap.Reconstruction to a Scene: registered images only, frames sorted by name,
    ``index`` 0..N-1, ``points`` from points3D (colours in ``point_colors``).

    image_dir: folder the image names are relative to (None: frames get no path).
    Images without a pose are listed in ``unregistered``.
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
    check_names([im.name for im in rec.images.values()], where, subfolders=True)  # before any file is touched
    frames, unregistered = [], []
    for img in sorted(rec.images.values(), key=lambda im: capture_key(im.name)):
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
                raise InputError(
                    f"{path}: image is {w_}x{h_} but COLMAP camera {img.camera_id} says {cam.width}x{cam.height}"
                )
        frames.append(Frame(name=img.name, pose=Pose(q, t), camera_id=int(img.camera_id), path=path))
    for i, f in enumerate(frames):
        f.index = float(i)
    points, colors, obs = None, None, {}
    if rec.num_points3D():
        ids = sorted(rec.points3D)  # by id: stable order
        points = np.array([rec.points3D[i].xyz for i in ids], dtype=np.float64).reshape(-1, 3)
        colors = np.array([rec.points3D[i].color for i in ids], dtype=np.uint8).reshape(-1, 3)
        keep = np.all(np.isfinite(points), axis=1)
        points, colors = points[keep], colors[keep]
        obs = _observations(rec, {pid: k for k, pid in enumerate(np.asarray(ids)[keep].tolist())})
    scene = Scene(
        cameras=cams,
        frames=frames,
        points=points,
        source=source,
        point_colors=colors,
        observations=obs,
        source_format="colmap",
        unregistered=tuple(unregistered),
    )
    return scene_cameras_dedup(scene)


def _observations(rec, point_index: dict[int, int]) -> dict[str, Observations]:
    """Each registered image's observations of the kept points, by image name."""
    out = {}
    for img in rec.images.values():
        if not img.has_pose:
            continue
        pairs = [
            (point_index[p.point3D_id], p.xy) for p in img.get_observation_points2D() if p.point3D_id in point_index
        ]
        if pairs:
            cam = rec.cameras[img.camera_id]
            out[img.name] = Observations(
                np.array([k for k, _ in pairs], dtype=np.int64),
                np.array([xy for _, xy in pairs], dtype=np.float64).reshape(-1, 2),
                (int(cam.width), int(cam.height)),
            )
    return out


def read_colmap(path: Path, images: Path | None = None, *, require_images: bool = True) -> Scene:
    """Read a COLMAP model folder (text or binary) and its images.

    path: a scene folder holding ``sparse/0`` (or ``sparse``), or the model folder itself.
    images: the images folder; default ``images/`` beside ``sparse/``.
    require_images: a registered image whose file is missing raises InputError (else its path is None).
    Masks in ``masks/`` beside ``images/`` (``<stem>.png`` for every image, as sparself writes a dense
    scene) become the frames' ``mask`` (:func:`sparself.capture.io.dense.read_masks_beside`).
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
    if not image_dir.is_dir():
        return scene_from_reconstruction(rec, None, source=model_dir, require_images=require_images)
    scene = scene_from_reconstruction(rec, image_dir, source=model_dir, require_images=require_images)
    return read_masks_beside(scene, image_dir)  # a dense scene's masks/ (its synthesized views' confidence)


def reconstruction_from_scene(scene: Scene):
    """A pycolmap.Reconstruction with the scene's cameras, frames (image ids 1..N in frame order) and
    points with tracks: a frame keeps its SfM observations (``Scene.observations``), any other frame
    (a synthesized view, or a scene read without tracks) observes the points that project into it."""
    pycolmap = import_native("pycolmap")

    rec = pycolmap.Reconstruction()
    for cid, cam in sorted(scene.cameras.items()):
        rec.add_camera_with_trivial_rig(
            pycolmap.Camera(
                model=cam.model, width=cam.width, height=cam.height, params=list(cam.params), camera_id=int(cid)
            )
        )
    points = np.zeros((0, 3)) if scene.points is None else np.asarray(scene.points, dtype=np.float64)
    tracks: list[list[tuple[int, int]]] = [[] for _ in range(len(points))]
    extra: list[np.ndarray] = []
    for i, f in enumerate(scene.frames):
        qw, qx, qy, qz = f.pose.qvec
        T = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([qx, qy, qz, qw])), f.pose.tvec.reshape(3, 1))
        idx, xy = frame_observations(scene, i, rec.cameras[f.camera_id])
        if not len(idx) and len(points):
            # a view that sees none of the points (gsplat's depth loss needs one per image): a point on
            # its optical axis at the scene's typical depth, observed at the principal point
            d = float(np.sqrt(np.prod(scene.depth_bounds())))
            extra.append(f.pose.R.T @ (np.array([0.0, 0.0, d]) - f.pose.tvec))
            tracks.append([])
            idx = np.array([len(tracks) - 1])
            xy = np.asarray(rec.cameras[f.camera_id].img_from_cam(np.array([[0.0, 0.0, d]]))).reshape(1, 2)
        for j, k in enumerate(idx):
            tracks[k].append((i + 1, j))
        pts2d = pycolmap.Point2DList([pycolmap.Point2D(np.asarray(p, dtype=np.float64)) for p in xy])
        rec.add_image_with_trivial_frame(
            pycolmap.Image(name=f.name, camera_id=int(f.camera_id), image_id=i + 1, points2D=pts2d), T
        )
    colors = scene.point_colors
    if colors is None or len(colors) != len(points):
        colors = np.full((len(points), 3), 128, dtype=np.uint8)
    colors = np.concatenate([np.asarray(colors, dtype=np.uint8), np.full((len(extra), 3), 128, np.uint8)])
    points = np.concatenate([points, np.reshape(extra, (-1, 3))])
    for p, c, els in zip(points, colors, tracks):
        track = pycolmap.Track()
        for image_id, point2d in els:
            track.add_element(image_id, point2d)
        rec.add_point3D(p, track, c)
    return rec


def frame_observations(scene: Scene, i: int, pycam) -> tuple[np.ndarray, np.ndarray]:
    """(point indices, (M, 2) pixels) that frame i observes: its stored SfM observations, scaled to its
    camera, else the points in front of it that project inside the image (``pycam``'s model, distortion
    included); possibly none."""
    f, cam = scene.frames[i], scene.camera(i)
    if scene.points is None or not len(scene.points):
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    stored = scene.observations.get(f.name)
    if stored is not None and not f.synthetic and len(stored.point) and stored.point.max() < len(scene.points):
        s = np.array([cam.width / stored.size[0], cam.height / stored.size[1]])
        return stored.point, stored.xy * s
    X = np.asarray(scene.points, dtype=np.float64) @ f.pose.R.T + f.pose.tvec
    front = np.flatnonzero(X[:, 2] > 1e-9)
    if not len(front):
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    uv = np.asarray(pycam.img_from_cam(X[front]), dtype=np.float64).reshape(-1, 2)
    ok = np.all(np.isfinite(uv), axis=1)
    inside = ok & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    return front[inside], uv[inside]


def write_colmap(scene: Scene, model_dir: Path, *, text: bool = False) -> Path:
    """Write the scene as a COLMAP model into ``model_dir`` (binary ``cameras/images/points3D.bin``;
    ``.txt`` instead when ``text``). Not atomic by itself: write into a folder from ``outputs.atomic_dir``."""
    model_dir = Path(model_dir)
    model_dir.mkdir(parents=True, exist_ok=True)
    rec = reconstruction_from_scene(scene)
    (rec.write_text if text else rec.write_binary)(str(model_dir))
    return model_dir
