"""Camera plots: original, planned and held-out cameras as 3D frusta (matplotlib, PNG)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import numpy as np

from sparself.capture.scene import Camera, Frame, Scene

log = logging.getLogger(__name__)

_STYLE = {
    "input": dict(color="tab:blue", label="input views"),
    "planned": dict(color="tab:orange", label="planned (novel) poses"),
    "held_out": dict(color="tab:green", label="held-out views"),
}


def frustum_lines(pose_c2w: np.ndarray, cam: Camera, size: float) -> np.ndarray:
    """Line segments of a camera frustum in world space: (8, 2, 3).

    The image rectangle is drawn at depth ``size`` (world units) through the camera's intrinsics, so
    the frustum shows both where the camera is and how wide it sees; the apex is the camera centre.
    """
    w, h = cam.width, cam.height
    px = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], dtype=np.float64)
    rays = px @ np.linalg.inv(cam.K).T  # camera coords at z = 1
    pts_cam = rays * size
    R, C = pose_c2w[:3, :3], pose_c2w[:3, 3]
    corners = pts_cam @ R.T + C
    segs = [(C, c) for c in corners] + [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    return np.array(segs)


def _draw(
    ax,
    frames: Sequence[Frame],
    cameras: dict[int, Camera],
    size: float,
    style: dict,
    path_line: bool,
    width: float = 0.7,
) -> None:
    if not frames:
        return
    default_cam = next(iter(cameras.values()))
    centers = []
    for k, f in enumerate(frames):
        cam = cameras.get(f.camera_id, default_cam)
        c2w = f.pose.c2w()
        for a, b in frustum_lines(c2w, cam, size):
            ax.plot(*zip(a, b), color=style["color"], linewidth=width)
        centers.append(c2w[:3, 3])
    xyz = np.array(centers)
    ax.scatter(*xyz.T, color=style["color"], s=8, label=f"{style['label']} ({len(frames)})")
    if path_line:
        ax.plot(*xyz.T, color=style["color"], linewidth=0.5, alpha=0.4, linestyle="--")


def plot_cameras(
    scene: Scene,
    planned: Sequence[Frame] | None = None,
    held_out: Sequence[Frame] | None = None,
    *,
    path: Path,
    title: str | None = None,
) -> Path:
    """Draw the scene's cameras (blue), planned poses (orange) and held-out views (green) to a PNG.

    planned / held_out: Frames whose camera_id refers to ``scene.cameras``. Frustum depth is 15% of
    the scene scale. Writes ``path`` directly (callers wanting atomicity pass a temporary path).
    """
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    size = 0.15 * scene.scale()
    fig = plt.figure(figsize=(8, 7), dpi=100)
    try:
        ax = fig.add_subplot(111, projection="3d")
        _draw(ax, scene.frames, scene.cameras, size, _STYLE["input"], path_line=True)
        _draw(ax, list(planned or []), scene.cameras, size, _STYLE["planned"], path_line=False, width=1.4)
        _draw(ax, list(held_out or []), scene.cameras, size, _STYLE["held_out"], path_line=False, width=1.4)
        pts = [scene.centers()] + [np.array([f.pose.center for f in fs]) for fs in (planned, held_out) if fs]
        every = np.concatenate(pts)
        lo, hi = every.min(0) - size, every.max(0) + size
        mid, half = (lo + hi) / 2, max((hi - lo).max() / 2, 1e-6)
        ax.set_xlim(mid[0] - half, mid[0] + half)
        ax.set_ylim(mid[1] - half, mid[1] + half)
        ax.set_zlim(mid[2] - half, mid[2] + half)
        ax.set_box_aspect((1, 1, 1))
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
        src = Path(scene.source) if scene.source is not None else None
        name = "scene" if src is None else (src.parent.name if src.suffix else src.name)
        ax.set_title(title or f"{name}: {len(scene)} input views, {len(planned or [])} planned")
        ax.legend(loc="upper left", fontsize=8)
        fig.tight_layout()
        fig.savefig(Path(path), format="png")
    finally:
        plt.close(fig)
    return Path(path)
