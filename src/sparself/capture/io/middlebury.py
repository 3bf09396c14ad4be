"""Middlebury multi-view stereo ``*_par.txt`` <-> :class:`Scene`.

Each row is ``name k11..k33 r11..r33 t1 t2 t3`` with ``x ~ K [R | t] X`` (world-to-camera, OpenCV axes):
exactly COLMAP's convention, so R and t are taken as they are. Rows whose image file is missing are
skipped (templeRing ships 19 of its 47 views).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from sparself.capture.images import image_size_of
from sparself.capture.io._common import check_finite, order_frames, unique_cameras
from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.errors import InputError
from sparself.core.geometry import Pose, rotmat_to_quat
from sparself.core.names import check_names

log = logging.getLogger(__name__)


def find_par_file(folder: Path) -> Path | None:
    """The single ``*_par.txt`` in a folder, else None (InputError when there are several)."""
    found = sorted(Path(folder).glob("*_par.txt"))
    if len(found) > 1:
        raise InputError(
            f"{folder}: several Middlebury pose files ({', '.join(p.name for p in found)}); pass the one to use"
        )
    return found[0] if found else None


def read_middlebury(path: Path) -> Scene:
    """Read a Middlebury ``*_par.txt`` (or a folder holding one) and the images beside it."""
    path = Path(path)
    par = find_par_file(path) if path.is_dir() else path
    if par is None or not par.is_file():
        raise InputError(f"{path}: no Middlebury *_par.txt file found")
    try:
        lines = [ln.split() for ln in par.read_text().splitlines() if ln.strip()]
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{par}: cannot read ({e})") from None
    if not lines or len(lines[0]) != 1 or not lines[0][0].isdigit():
        raise InputError(f"{par}: first line must be the number of views")
    n = int(lines[0][0])
    rows = lines[1:]
    if len(rows) != n:
        raise InputError(f"{par}: header says {n} views but {len(rows)} rows follow")
    folder = par.parent
    frames, cams = [], []
    for r, row in enumerate(rows, start=2):
        if len(row) != 22:
            raise InputError(f"{par}: line {r} has {len(row)} fields, expected 22 (name + K, R, t)")
        try:
            vals = np.array([float(v) for v in row[1:]], dtype=np.float64)
        except ValueError:
            raise InputError(f"{par}: line {r} has a non-numeric value") from None
        check_finite(vals, f"{par}: line {r}")
        img = folder / row[0]
        if not img.is_file():
            continue
        K, R, t = vals[:9].reshape(3, 3), vals[9:18].reshape(3, 3), vals[18:21]
        if abs(np.linalg.det(R) - 1.0) > 1e-3 or np.abs(R @ R.T - np.eye(3)).max() > 1e-3:
            raise InputError(f"{par}: line {r}: R is not a rotation matrix")
        w, h = image_size_of(img)
        cams.append(Camera.pinhole(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        frames.append(Frame(name=row[0], pose=Pose(rotmat_to_quat(R), t), path=img))
    if not frames:
        raise InputError(f"{par}: none of the {n} listed images exists in {folder}")
    check_names([f.name for f in frames], par)
    if len(frames) < n:
        log.info("%s: %d of %d listed views have no image file; skipped", par.name, n - len(frames), n)
    cameras, ids = unique_cameras(cams)
    for f, cid in zip(frames, ids):
        f.camera_id = cid
    return order_frames(Scene(cameras=cameras, frames=frames, source=par, source_format="middlebury"))


def write_middlebury(scene: Scene, path: Path) -> Path:
    """Write ``*_par.txt`` rows for the scene's frames (pinhole K; distortion is dropped)."""
    path = Path(path)
    lines = [str(len(scene.frames))]
    for i, f in enumerate(scene.frames):
        vals = np.concatenate([scene.camera(i).K.ravel(), f.pose.R.ravel(), f.pose.tvec])
        lines.append(" ".join([f.name] + [repr(float(v)) for v in vals]))
    path.write_text("\n".join(lines) + "\n")
    return path
