"""nerfstudio / NeRF ``transforms.json`` <-> :class:`Scene`.

``transform_matrix`` is camera-to-world with OpenGL camera axes (x right, y up, z back): the OpenCV
camera-to-world with its y and z columns negated. Intrinsics are global (``fl_x fl_y cx cy w h
camera_model`` + distortion ``k1 k2 k3 k4 p1 p2``) or per frame; the NeRF-synthetic form gives only
``camera_angle_x`` (image size then comes from the files). A nerfstudio ``applied_transform`` (the world
change that ns-process-data applies to COLMAP poses) is undone on read, so poses come back in the
COLMAP world; our writer applies none.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np

from sparself.capture.images import image_size_of
from sparself.capture.io._common import check_finite, frame_name_order, in_capture_order, unique_cameras
from sparself.capture.io.dense import MASKS, checked_mask, mask_name
from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.errors import InputError
from sparself.core.geometry import Pose
from sparself.core.names import check_names

log = logging.getLogger(__name__)

FILENAME = "transforms.json"
_GL = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV <-> OpenGL camera axes (its own inverse)
_DIST_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


def _camera(d: dict, img: Path | None, where: str) -> Camera:
    """Camera from a dict of nerfstudio intrinsics keys (the global ones updated by the frame's)."""
    try:
        return _read_camera(d, img, where)
    except (TypeError, ValueError, OverflowError):  # a list, null or huge integer where a number belongs
        raise InputError(f"{where}: intrinsics (w, h, fl_x, fl_y, cx, cy, k1...) must be numbers") from None


def _read_camera(d: dict, img: Path | None, where: str) -> Camera:
    if "w" in d and "h" in d:
        w, h = int(d["w"]), int(d["h"])
    elif img is not None:
        w, h = image_size_of(img)
    else:
        raise InputError(f"{where}: no image size (w, h) and no image to read it from")
    if "fl_x" in d or "fl_y" in d:
        fx = float(d["fl_x"] if "fl_x" in d else d["fl_y"])
        fy = float(d.get("fl_y", fx))
    elif "camera_angle_x" in d:
        fx = 0.5 * w / math.tan(0.5 * float(d["camera_angle_x"]))
        fy = 0.5 * h / math.tan(0.5 * float(d["camera_angle_y"])) if "camera_angle_y" in d else fx
    else:
        raise InputError(f"{where}: no focal length (fl_x/fl_y or camera_angle_x)")
    cx, cy = float(d.get("cx", w / 2.0)), float(d.get("cy", h / 2.0))
    dist = {k: float(d.get(k, 0.0)) for k in _DIST_KEYS}
    check_finite([fx, fy, cx, cy, *dist.values()], f"{where}: intrinsics")
    if fx <= 0 or fy <= 0:
        raise InputError(f"{where}: focal length must be positive, got fl_x={fx}, fl_y={fy}")
    model = str(d.get("camera_model", "OPENCV")).upper()
    if model == "OPENCV_FISHEYE":
        return Camera(model, w, h, (fx, fy, cx, cy, dist["k1"], dist["k2"], dist["k3"], dist["k4"]))
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        raise InputError(f"{where}: camera_model {model!r} is not supported (pinhole / OpenCV models only)")
    if any(dist[k] for k in ("k1", "k2", "k3", "p1", "p2")):
        if dist["k4"]:
            log.warning("%s: distortion k4 dropped (an r^8 term that OpenCV's camera models lack)", where)
        k1, k2, p1, p2, k3 = (dist[k] for k in ("k1", "k2", "p1", "p2", "k3"))
        if k3:  # OpenCV's k3 is the r^6 term, as nerfstudio's
            return Camera("FULL_OPENCV", w, h, (fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0))
        return Camera("OPENCV", w, h, (fx, fy, cx, cy, k1, k2, p1, p2))
    return Camera.pinhole(w, h, fx, fy, cx, cy)


def _resolve(base: Path, file_path: str) -> Path:
    p = base / file_path
    if p.suffix.lower() not in (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp") and not p.is_file():
        for ext in (".png", ".jpg", ".jpeg"):  # NeRF-synthetic paths omit the extension
            if p.with_name(p.name + ext).is_file():
                return p.with_name(p.name + ext)
    return p


def _mask(fr: dict, js: Path, cam: Camera, where: str) -> Path | None:
    """A frame's ``mask_path`` (relative to ``transforms.json``), checked
    (:func:`sparself.capture.io.dense.checked_mask`):
    None when it has none or it is all 255; InputError naming the file when it is missing or unreadable."""
    if fr.get("mask_path") is None:
        return None
    if not isinstance(fr["mask_path"], str):
        raise InputError(f"{where}: mask_path must be a file name, got {fr['mask_path']!r}")
    return checked_mask(js.parent / fr["mask_path"], (cam.width, cam.height), f"mask_path of {where}")


def _unapply(meta: dict, js: Path) -> np.ndarray:
    """The inverse of nerfstudio's ``applied_transform`` (identity when there is none). -> (4, 4)."""
    applied = np.eye(4)
    if "applied_transform" in meta:
        A = np.asarray(meta["applied_transform"], dtype=np.float64)
        if A.shape not in ((3, 4), (4, 4)):
            raise InputError(f"{js}: applied_transform must be 3x4 or 4x4, got shape {A.shape}")
        check_finite(A, f"{js}: applied_transform")
        applied[:3] = A[:3]
    return np.linalg.inv(applied)


def read_nerfstudio(path: Path, *, require_images: bool = True) -> Scene:
    """Read ``transforms.json`` (or a folder holding it). Frames are sorted by image name. A frame's
    ``mask_path`` (nerfstudio's per-pixel mask; sparself writes synthesized views' confidence there) becomes
    its ``mask``: read when used, as confidence value / 255, none for an all-255 mask (a real photo)."""
    path = Path(path)
    js = path / FILENAME if path.is_dir() else path
    if not js.is_file():
        raise InputError(f"{path}: no {FILENAME} found")
    try:
        meta = json.loads(js.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"{js}: cannot parse JSON ({e})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        raise InputError(f"{js}: expected an object with a non-empty 'frames' list")
    unapply = _unapply(meta, js)
    glob_keys = {k: v for k, v in meta.items() if k != "frames"}
    frames, cams = [], []
    for i, fr in enumerate(meta["frames"]):
        where = f"{js}: frame {i}"
        if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
            raise InputError(f"{where}: needs 'file_path' and 'transform_matrix'")
        try:
            M = np.asarray(fr["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise InputError(f"{where}: transform_matrix is not a numeric matrix") from None
        if M.shape not in ((4, 4), (3, 4)):
            raise InputError(f"{where}: transform_matrix must be 4x4 (or 3x4), got shape {M.shape}")
        check_finite(M, f"{where} ({fr['file_path']}): transform_matrix")
        c2w_gl = np.eye(4)
        c2w_gl[:3] = M[:3]
        c2w = unapply @ c2w_gl @ _GL
        R = c2w[:3, :3]
        if abs(np.linalg.det(R) - 1.0) > 1e-3 or np.abs(R.T @ R - np.eye(3)).max() > 1e-3:
            raise InputError(f"{where} ({fr['file_path']}): rotation is not orthonormal (scaled or sheared)")
        img = _resolve(js.parent, str(fr["file_path"]))
        if not img.is_file():
            if require_images:
                raise InputError(f"{img}: image file not found (listed in {js})")
            img_path = None
        else:
            img_path = img
        cams.append(_camera({**glob_keys, **fr}, img_path, where))
        name = Path(str(fr["file_path"])).name if img_path is None else img_path.name
        frames.append(
            Frame(
                name=name,
                pose=Pose.from_c2w(c2w),
                path=img_path,
                synthetic=fr.get("synthetic") is True,
                mask=None if img_path is None else _mask(fr, js, cams[-1], where),
            )
        )
    check_names([f.name for f in frames], js)
    cameras, ids = unique_cameras(cams)
    for f, cid in zip(frames, ids):
        f.camera_id = cid
    scene = Scene(cameras=cameras, frames=frames, source=js, source_format="nerfstudio")
    if isinstance(meta.get("ply_file_path"), str) and (js.parent / meta["ply_file_path"]).is_file():
        scene.points, colors = _read_ply(js.parent / meta["ply_file_path"])
        if colors is not None:
            scene.point_colors = colors
    return in_capture_order(scene)


def _intrinsics(cam: Camera) -> dict:
    d: dict[str, float | str] = {
        "fl_x": cam.fx,
        "fl_y": cam.fy,
        "cx": cam.cx,
        "cy": cam.cy,
        "w": cam.width,
        "h": cam.height,
    }
    p = cam.params
    if cam.model in ("SIMPLE_PINHOLE", "PINHOLE"):
        d["camera_model"] = "OPENCV"
    elif cam.model == "SIMPLE_RADIAL":
        d.update(camera_model="OPENCV", k1=p[3])
    elif cam.model == "RADIAL":
        d.update(camera_model="OPENCV", k1=p[3], k2=p[4])
    elif cam.model == "OPENCV":
        d.update(camera_model="OPENCV", k1=p[4], k2=p[5], p1=p[6], p2=p[7])
    elif cam.model == "FULL_OPENCV" and not any(p[9:]):  # nerfstudio's k3 is OpenCV's: an r^6 numerator term
        d.update(camera_model="OPENCV", k1=p[4], k2=p[5], p1=p[6], p2=p[7], k3=p[8])
    elif cam.model.endswith("FISHEYE") and cam.lens is not None:
        D = cam.lens[0]
        d.update(camera_model="OPENCV_FISHEYE", k1=D[0], k2=D[1], k3=D[2], k4=D[3])
    else:
        log.warning("camera model %s has no nerfstudio equivalent; written as undistorted OPENCV", cam.model)
        d["camera_model"] = "OPENCV"
    return d


def transforms_dict(scene: Scene, image_prefix: str = "images/", split=None, masks: bool = False) -> dict:
    """The ``transforms.json`` content: global intrinsics when the scene has one camera, else per frame;
    each frame flagged ``"synthetic"``; with a :class:`sparself.capture.io.dense.DenseSplit`, the ``train_filenames``,
    ``val_filenames`` and ``test_filenames`` lists (nerfstudio needs all three when one is present);
    with ``masks``, each frame's ``mask_path`` (``masks/<stem>.png``, :func:`sparself.capture.io.dense.write_masks`)."""
    order = frame_name_order(scene)
    one = len({scene.frames[i].camera_id for i in order}) == 1
    out: dict = dict(_intrinsics(scene.camera(order[0]))) if one else {}
    frames = []
    for i in order:
        f = scene.frames[i]
        fr = {
            "file_path": image_prefix + f.name,
            "transform_matrix": (f.pose.c2w() @ _GL).tolist(),
            "synthetic": bool(f.synthetic),
        }
        if masks:
            fr["mask_path"] = f"{MASKS}/{mask_name(f.name)}"
        if not one:
            fr.update(_intrinsics(scene.camera(i)))
        frames.append(fr)
    out["frames"] = frames
    if scene.points is not None and len(scene.points):
        out["ply_file_path"] = "sparse_pc.ply"
    if split is not None and split.test:  # no test split: nerfstudio's own rule
        for key in ("train", "val", "test"):
            out[f"{key}_filenames"] = [image_prefix + n for n in getattr(split, key)]
    return out


def write_nerfstudio(
    scene: Scene, out_dir: Path, image_prefix: str = "images/", split=None, masks: bool = False
) -> Path:
    """Write ``out_dir/transforms.json`` (and ``sparse_pc.ply`` when the scene has points, which
    nerfstudio's splatfacto uses to initialise). Not atomic by itself: use ``outputs.atomic_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    d = transforms_dict(scene, image_prefix, split, masks)
    if "ply_file_path" in d:
        _write_ply(out_dir / d["ply_file_path"], np.asarray(scene.points), scene.point_colors)
    out = out_dir / FILENAME
    out.write_text(json.dumps(d, indent=2))
    return out


_PLY_TYPES = {
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
    "uchar": "u1",
    "uint8": "u1",
    "char": "i1",
    "int8": "i1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
}


def _read_ply(path: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Vertices (x, y, z) and colours (red, green, blue, if present) of a point-cloud PLY (ASCII or
    binary, vertex element first, as nerfstudio and sparself write them); (None, None) with a warning
    for anything else, since the points are only an extra."""
    try:
        raw = Path(path).read_bytes()
        end = raw.index(b"end_header") + len(b"end_header")
        end += 2 if raw[end : end + 2] == b"\r\n" else 1
        header = raw[:end].decode("ascii").split("\n")
        fmt = next(h.split()[1] for h in header if h.startswith("format"))
        n = int(next(h.split()[2] for h in header if h.startswith("element vertex")))
        start = next(k for k, h in enumerate(header) if h.startswith("element vertex"))
        props = []
        for h in header[start + 1 :]:
            if not h.startswith("property"):
                break
            props.append((h.split()[2], _PLY_TYPES[h.split()[1]]))
        if fmt == "ascii":
            rows = np.loadtxt(raw[end:].decode("ascii").splitlines()[:n], ndmin=2)
            data = {name: rows[:, k] for k, (name, _) in enumerate(props)}
        else:
            order = "<" if fmt == "binary_little_endian" else ">"
            arr = np.frombuffer(raw, np.dtype([(name, order + t) for name, t in props]), count=n, offset=end)
            data = {name: arr[name] for name, _ in props}
        pts = np.stack([data["x"], data["y"], data["z"]], axis=1).astype(np.float64)
        rgb = np.stack([data[c] for c in ("red", "green", "blue")], 1).astype(np.uint8) if "red" in data else None
    except (OSError, ValueError, KeyError, StopIteration, IndexError, UnicodeDecodeError) as e:
        log.warning("%s: cannot read the point cloud (%s); the scene is read without points", path, e)
        return None, None
    keep = np.all(np.isfinite(pts), axis=1)
    return pts[keep], None if rgb is None else rgb[keep]


def _write_ply(path: Path, points: np.ndarray, colors: np.ndarray | None) -> None:
    """ASCII PLY with float xyz and uchar rgb (the form nerfstudio's colmap export writes)."""
    if colors is None or len(colors) != len(points):
        colors = np.full((len(points), 3), 128, dtype=np.uint8)
    header = (
        "ply\nformat ascii 1.0\n"
        f"element vertex {len(points)}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uint8 red\nproperty uint8 green\nproperty uint8 blue\nend_header\n"
    )
    lines = [
        f"{p[0]:.8g} {p[1]:.8g} {p[2]:.8g} {int(c[0])} {int(c[1])} {int(c[2])}"
        for p, c in zip(points, np.asarray(colors, dtype=np.uint8))
    ]
    path.write_text(header + "\n".join(lines) + ("\n" if lines else ""))
