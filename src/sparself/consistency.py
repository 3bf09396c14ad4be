"""Do a trained run and a scene belong together? (resume, synthesize)

A run records its training views' names and the centre and scale of their cameras (``meta``: "sources",
"center", "scale"); a scene that differs in any of them is another capture, or another subset of it, and
the network's pose normalisation and its learned views do not apply to it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError
from .scene import Scene


def run_scene_mismatch(meta: dict, scene: Scene, holdout: tuple[int, ...] = ()) -> str | None:
    """How ``scene`` (minus ``holdout``) differs from the run's training views, or None if it does not.

    Checks only what the run recorded (older runs lack some of it); reads no image."""
    keep = [i for i in range(len(scene)) if i not in set(holdout)]
    names = sorted(scene.frames[i].name for i in keep)
    ran = meta.get("sources")
    if isinstance(ran, list):
        if len(ran) != len(names):
            return f"the run was trained on {len(ran)} views, this scene has {len(names)}"
        odd = sorted(set(map(str, ran)) ^ set(names))
        if odd:
            return f"other views (in only one of the two: {', '.join(odd[:3])}{', ...' if len(odd) > 3 else ''})"
    c, s = meta.get("center"), meta.get("scale")
    if c is not None and s is not None and keep:
        sub = scene.subset(keep)
        tol = 1e-3 * max(float(s), 1e-12)
        if np.linalg.norm(sub.centers().mean(0) - np.asarray(c, float)) > tol or abs(sub.scale() - float(s)) > tol:
            return "same view names, but the cameras are elsewhere (another capture?)"
    return None


def recorded_scene(meta: dict, run_path: Path) -> Path:
    """The scene a run was trained on, as recorded; InputError saying "pass --scene" when it is gone."""
    rec = meta.get("scene")
    if not rec:
        raise InputError(f"{run_path}: the run does not record its scene; pass --scene")
    p = Path(rec)
    if not p.exists():
        raise InputError(f"{run_path}: the run's scene {p} is not there any more (moved or deleted?); "
                         "pass --scene with its new location")
    return p
