"""Small helpers shared by the format readers/writers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

from sparself.capture.scene import Camera, Scene
from sparself.core.errors import InputError
from sparself.core.names import capture_key


def check_finite(arr: npt.ArrayLike, what: str) -> None:
    """Raise InputError('<what> contains NaN or inf ...') when ``arr`` has a non-finite value."""
    arr = np.asarray(arr, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))
        where = f" (first at index {tuple(int(i) for i in bad[0])})" if arr.ndim > 1 else ""
        raise InputError(f"{what} contains NaN or inf{where}")


def find_image(folder: Path, name: str, *, required: bool = True, what: str = "") -> Path | None:
    """``folder/name`` if it is a file; else InputError (required) or None."""
    p = Path(folder) / name
    if p.is_file():
        return p
    if required:
        raise InputError(f"{p}: image file not found{' (listed in ' + what + ')' if what else ''}")
    return None


def scene_cameras_dedup(scene: Scene) -> Scene:
    """Merge cameras with identical model, size and parameters into the lowest id (COLMAP exports often
    hold one camera per image even when every image shares the same intrinsics)."""
    first: dict[Camera, int] = {}
    remap: dict[int, int] = {}
    for cid in sorted(scene.cameras):
        remap[cid] = first.setdefault(scene.cameras[cid], cid)
    if all(k == v for k, v in remap.items()):
        return scene
    for f in scene.frames:
        f.camera_id = remap[f.camera_id]
    scene.cameras = {cid: cam for cid, cam in scene.cameras.items() if remap[cid] == cid}
    return scene


def unique_cameras(cams: list[Camera]) -> tuple[dict[int, Camera], list[int]]:
    """Cameras numbered 1.. in first-seen order, and each input's id. -> (cameras, ids)."""
    ids: dict[Camera, int] = {}
    out = []
    for c in cams:
        out.append(ids.setdefault(c, len(ids) + 1))
    return {i: c for c, i in ids.items()}, out


def order_frames(scene: Scene) -> Scene:
    """Sort frames by image name in capture order (IMG_2 before IMG_10) and set ``index`` to 0..N-1."""
    scene.frames.sort(key=lambda f: capture_key(f.name))
    for i, f in enumerate(scene.frames):
        f.index = float(i)
    return scene


def frame_name_order(scene: Scene) -> list[int]:
    """Frame indices in plain text order of the names: the order LLFF/nerfstudio tools list ``images/``
    (not the capture order; a written dense scene's rank prefixes make the two agree)."""
    return sorted(range(len(scene.frames)), key=lambda i: scene.frames[i].name)
