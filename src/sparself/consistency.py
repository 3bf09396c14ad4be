"""Do a trained run and a scene belong together? (resume, synthesize)

A run records its training views' names and the centre and scale of their cameras (``RunMeta``: sources,
center, scale); a scene that differs in any of them is another capture, or another subset of it, and the
network's pose normalisation and its learned views do not apply to it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError
from .scene import Scene

if TYPE_CHECKING:
    from .train import RunMeta


def run_scene_mismatch(meta: "RunMeta", scene: Scene, holdout: tuple[int, ...] = ()) -> str | None:
    """How ``scene`` (minus ``holdout``) differs from the run's training views, or None if it does not.
    Reads no image."""
    sub = scene.without(holdout)
    names = sorted(f.name for f in sub.frames)
    if len(meta.sources) != len(names):
        return f"the run was trained on {len(meta.sources)} views, this scene has {len(names)}"
    odd = sorted(set(map(str, meta.sources)) ^ set(names))
    if odd:
        return f"other views (in only one of the two: {', '.join(odd[:3])}{', ...' if len(odd) > 3 else ''})"
    if len(sub):
        tol = 1e-3 * max(float(meta.scale), 1e-12)
        if (np.linalg.norm(sub.centers().mean(0) - np.asarray(meta.center, float)) > tol
                or abs(sub.scale() - float(meta.scale)) > tol):
            return "same view names, but the cameras are elsewhere (another capture?)"
    return None


def recorded_scene(meta: "RunMeta", run_path: Path) -> Path:
    """The scene a run was trained on, as recorded; InputError saying "pass --scene" when it is gone."""
    if not meta.scene:
        raise InputError(f"{run_path}: the run does not record its scene; pass --scene")
    p = Path(meta.scene)
    if not p.exists():
        raise InputError(f"{run_path}: the run's scene {p} is not there any more (moved or deleted?); "
                         "pass --scene with its new location")
    return p
