"""LLFF ``poses_bounds.npy`` <-> :class:`Scene`.

Layout (Mildenhall et al. 2019): float64 (N, 17), one row per image of ``images/`` in sorted file-name
order. ``row[:15].reshape(3, 5) = [down | right | back | centre | hwf]``: the first three columns are the
camera-to-world rotation with columns (+y, +x, -z) of the COLMAP/OpenCV camera, column 3 the camera centre
in world coordinates, column 4 ``[H, W, focal]``; ``row[15:17]`` = near, far depth bounds of that view.

Each row holds one focal length (fx == fy) and assumes the principal point at the image centre: other
intrinsics are approximated on write (with a warning) and come back as a centred PINHOLE camera. NeRF's loader
(``load_llff_data``) moreover reads the first row's focal length and size for every image: a write whose views
differ there says so (:func:`_one_camera_note`).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from sparself.capture.images import image_size_of, list_images
from sparself.capture.io._common import check_finite, frame_name_order, in_capture_order, unique_cameras
from sparself.capture.io.dense import read_masks_beside
from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.errors import InputError
from sparself.core.geometry import Pose
from sparself.core.names import check_names

log = logging.getLogger(__name__)

FILENAME = "poses_bounds.npy"


def _load_array(path: Path) -> np.ndarray:
    try:
        with open(path, "rb") as f:
            head = f.read(6)
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    if head != b"\x93NUMPY":  # numpy's own message for this speaks of pickles
        what = "empty (0 bytes)" if not head else "not a numpy .npy file"
        raise InputError(f"{path}: {what}; expected LLFF poses saved with numpy.save (an (N, 17) array)")
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise InputError(f"{path}: cannot read numpy array ({e}); the file may be truncated or corrupt") from None
    if arr.ndim != 2 or arr.shape[1] != 17 or arr.shape[0] == 0:
        raise InputError(f"{path}: expected an (N, 17) array of LLFF poses and bounds, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise InputError(f"{path}: expected numbers, got dtype {arr.dtype}")
    if np.iscomplexobj(arr):
        if np.any(arr.imag != 0):
            raise InputError(f"{path}: expected real numbers, got complex values (dtype {arr.dtype})")
        arr = arr.real
    arr = arr.astype(np.float64)
    check_finite(arr, str(path))
    return arr


def _count_mismatch(npy: Path, n_poses: int, files: list[Path], image_dir: Path) -> str:
    """The message for a pose/image count mismatch, naming the images that are probably extra: those
    missing from a COLMAP model beside the pose file (LLFF's imgs2poses leaves one), else the newest."""
    msg = f"{npy}: {n_poses} poses but {len(files)} images in {image_dir}"
    extra = len(files) - n_poses
    if extra <= 0:
        return msg + " (an image is missing: rows are matched to images in sorted name order)"
    from sparself.capture.io.colmap import find_model_dir, load_reconstruction

    model, why = find_model_dir(npy.parent), ""
    if model is not None:
        try:
            posed = {im.name for im in load_reconstruction(model).images.values()}
        except InputError:
            posed = set()
        odd = [f.name for f in files if f.name not in posed] if posed else []
        if 0 < len(odd) <= extra:
            names, why = odd, f"not in the COLMAP model {model}"
    if not why:
        names = [f.name for f in sorted(files, key=lambda f: f.stat().st_mtime_ns)[-extra:]]
        why = "the newest; rows are matched to images in sorted name order, so which is extra is a guess"
    shown = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    return f"{msg}: remove or move the extra {'image' if extra == 1 else 'images'} {shown} ({why})"


def llff_to_c2w(mat: np.ndarray) -> np.ndarray:
    """(3, 4) LLFF ``[down, right, back, centre]`` -> (4, 4) camera-to-world in OpenCV axes."""
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = mat[:, 1], mat[:, 0], -mat[:, 2], mat[:, 3]
    return c2w


def c2w_to_llff(c2w: np.ndarray) -> np.ndarray:
    """(4, 4) or (3, 4) OpenCV camera-to-world -> (3, 4) LLFF ``[down, right, back, centre]``."""
    return np.stack([c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3]], axis=1)


def read_llff(path: Path, images: Path | None = None) -> Scene:
    """Read ``poses_bounds.npy`` (or a folder holding it) with the images of ``images/`` beside it.

    If the images are smaller than the stored [H, W] (a downscaled ``images_4`` folder passed as
    ``images``), focal lengths are scaled to them, as NeRF's loader does.
    ``Scene.bounds`` = (min near, max far); per-view bounds are in ``frame_bounds`` by name.
    Masks beside the images (``masks/`` for ``images/``, ``masks_4/`` for ``images_4/``; ``<stem>.png`` for
    every image) become the frames' ``mask`` (:func:`sparself.capture.io.dense.read_masks_beside`).
    """
    path = Path(path)
    npy = path / FILENAME if path.is_dir() else path
    if not npy.is_file():
        raise InputError(f"{path}: no {FILENAME} found")
    arr = _load_array(npy)
    image_dir = Path(images) if images is not None else npy.parent / "images"
    files = sorted(list_images(image_dir), key=lambda p: p.name)  # rows follow plain text order, as LLFF's loaders
    check_names([p.name for p in files], image_dir)
    if len(files) != len(arr):
        raise InputError(_count_mismatch(npy, len(arr), files, image_dir))
    frames, cams, frame_bounds = [], [], {}
    scaled: dict[tuple, list[str]] = {}  # image size -> the views scaled to it
    for i, (row, img) in enumerate(zip(arr, files)):
        m = row[:15].reshape(3, 5)
        R = m[:, :3]
        with np.errstate(all="ignore"):  # huge or tiny entries: the check below fails them (NaN included)
            rotation = abs(np.linalg.det(R) - 1.0) <= 1e-3 and np.abs(R.T @ R - np.eye(3)).max() <= 1e-3
        if not rotation:
            raise InputError(
                f"{npy}: row {i} ({img.name}): rotation columns are not orthonormal "
                "(det must be +1 in [down, right, back] order)"
            )
        h, w, focal = m[:, 4]
        near, far = row[15], row[16]
        if h <= 0 or w <= 0 or focal <= 0 or not (0 < near < far):
            raise InputError(
                f"{npy}: row {i} ({img.name}): need H, W, focal > 0 and 0 < near < far, "
                f"got H={h}, W={w}, focal={focal}, near={near}, far={far}"
            )
        iw, ih = image_size_of(img)
        with np.errstate(over="ignore"):  # a tiny H or W gives inf, which the aspect check rejects
            sx, sy = iw / w, ih / h
        if (iw, ih) != (int(round(w)), int(round(h))):
            if not abs(sx - sy) <= 0.02:
                raise InputError(f"{img}: image is {iw}x{ih} but {npy.name} says {w:g}x{h:g} (aspect differs)")
            scaled.setdefault((iw, ih, w, h, sx), []).append(img.name)
        cams.append(Camera("SIMPLE_PINHOLE", iw, ih, (focal * sx, iw / 2.0, ih / 2.0)))
        frames.append(Frame(name=img.name, pose=Pose.from_c2w(llff_to_c2w(m[:, :4])), index=float(i), path=img))
        frame_bounds[img.name] = (float(near), float(far))
    _say_scaled(npy, scaled, len(files))
    cameras, ids = unique_cameras(cams)
    for f, cid in zip(frames, ids):
        f.camera_id = cid
    bounds = (float(arr[:, 15].min()), float(arr[:, 16].max()))
    scene = Scene(
        cameras=cameras,
        frames=frames,
        bounds=bounds,
        source=npy,
        source_format="llff",
        frame_bounds=frame_bounds,
    )
    return read_masks_beside(in_capture_order(scene), image_dir)  # indices in capture order


def _say_scaled(npy: Path, scaled: dict[tuple, list[str]], n: int) -> None:
    """Once per image size, not once per view: which views' focal lengths were scaled to their images."""
    for (iw, ih, w, h, sx), names in scaled.items():
        msg = "%s: %d of %d images are %dx%d, poses say %gx%g; scaling focal by %.4f"
        log.info(msg, npy.name, len(names), n, iw, ih, w, h, sx)


def _frame_bounds(scene: Scene, i: int) -> tuple[float, float] | None:
    """Near/far of frame i from the sparse points it sees (LLFF's 0.1 / 99.9 percentiles)."""
    if scene.points is None or len(scene.points) < 10:
        return None
    f, cam = scene.frames[i], scene.camera(i)
    X = scene.points @ f.pose.R.T + f.pose.tvec
    z = X[:, 2]
    front = z > 1e-9
    uv = (X[front] @ cam.K.T)[:, :2] / z[front, None]
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    zs = z[front][inside]
    if len(zs) < 10:
        return None
    near, far = np.percentile(zs, 0.1), np.percentile(zs, 99.9)
    return (float(near), float(far)) if 0 < near < far else None


APPROX_WARN = 0.01  # LLFF's one focal and centred principal point off by more than 1 %: worth a warning


def llff_array(scene: Scene) -> tuple[np.ndarray, list[int]]:
    """(N, 17) LLFF rows in image-name order and the frame index of each row.

    Near/far per view: ``frame_bounds`` if it has the frame, else from the sparse points in
    view, else the scene's global :meth:`Scene.depth_bounds`.
    """
    order = frame_name_order(scene)
    known = scene.frame_bounds
    global_bounds = None
    rows, approx, material = [], [], False
    for i in order:
        f, cam = scene.frames[i], scene.camera(i)
        if (
            abs(cam.fx - cam.fy) > 1e-6 * cam.fx
            or abs(cam.cx - cam.width / 2) > 0.5
            or abs(cam.cy - cam.height / 2) > 0.5
        ):
            approx.append(f"{f.name} (fx={cam.fx:.2f} fy={cam.fy:.2f} cx={cam.cx:.2f} cy={cam.cy:.2f})")
            off = max(abs(cam.fx - cam.fy) / cam.fx, abs(cam.cx / cam.width - 0.5), abs(cam.cy / cam.height - 0.5))
            material |= off > APPROX_WARN
        b = known.get(f.name) or _frame_bounds(scene, i)
        if b is None:
            global_bounds = global_bounds or scene.depth_bounds()
            b = global_bounds
        m = np.concatenate([c2w_to_llff(f.pose.c2w()), [[cam.height], [cam.width], [cam.fx]]], axis=1)
        rows.append(np.concatenate([m.ravel(), b]))
    if approx:  # once per write: a scene with one camera per photo would repeat it for every photo
        log.log(
            logging.WARNING if material else logging.INFO,
            "LLFF stores one focal and a centred principal point; the camera of %d view(s) is approximated, e.g. %s",
            len(approx),
            approx[0],
        )
    _one_camera_note(scene, order)
    return np.asarray(rows, dtype=np.float64), order


def _one_camera_note(scene: Scene, order: list[int]) -> None:
    """A warning, once per write, when the views' focal lengths differ by more than ``APPROX_WARN`` or their
    image sizes differ: NeRF's LLFF loader would give every image the first row's."""
    cams = [scene.camera(i) for i in order]
    focal = np.array([c.fx for c in cams])
    sizes = {(c.width, c.height) for c in cams}
    differ = []
    if len(cams) > 1 and focal.max() > focal.min() * (1 + APPROX_WARN):
        differ.append(f"focal lengths from {focal.min():.1f} to {focal.max():.1f} px")
    if len(sizes) > 1:
        differ.append(f"{len(sizes)} image sizes")
    if differ:
        log.warning(
            "%s keeps each view's camera, but NeRF's LLFF loader takes the first row's focal length and size for "
            "every image; these views have %s: with such a loader, use the scene's COLMAP model or "
            "transforms.json, which keep each view's camera",
            FILENAME,
            " and ".join(differ),
        )


def write_llff(scene: Scene, out_dir: Path) -> Path:
    """Write ``out_dir/poses_bounds.npy`` (rows in image-name order, matching ``images/`` listings).
    Not atomic by itself: write into a folder from ``outputs.atomic_dir``."""
    names = [f.name for f in scene.frames]
    if any("/" in n or "\\" in n for n in names):
        raise InputError("LLFF needs flat image names (no sub-folders): " + ", ".join(n for n in names if "/" in n))
    arr, _ = llff_array(scene)
    out = Path(out_dir) / FILENAME
    out.parent.mkdir(parents=True, exist_ok=True)
    np.save(out, arr)
    return out
