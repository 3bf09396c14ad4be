"""The order of a capture's views for planning: capture order, a greedy nearest-neighbour path, or ``auto``
(capture order unless its path is much longer), and the fractional indices along it."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from sparself.capture.scene import Scene
from sparself.core.errors import ConfigError, InputError

log = logging.getLogger(__name__)


AUTO_RATIO = 1.5  # "auto" switches to the nearest-neighbour path when capture order walks this much further


def step_costs(centers: np.ndarray, quats: np.ndarray, scale: float, i: int, js: np.ndarray) -> np.ndarray:
    """Distance from view i to views js: centre distance / scale + rotation angle (rad). -> (len(js),)"""
    d = np.linalg.norm(centers[js] - centers[i], axis=1) / scale
    dots = np.clip(np.abs(quats[js] @ quats[i]), 0.0, 1.0)
    return d + 2.0 * np.arccos(dots)


def path_length(scene: Scene, order: np.ndarray) -> float:
    """Length of the path visiting the views in ``order`` (same distance as the ordering uses)."""
    centers, quats, scale = scene.centers(), np.stack([p.qvec for p in scene.poses]), scene.scale()
    order = np.asarray(order)
    if len(order) < 2:
        return 0.0
    d = np.linalg.norm(np.diff(centers[order], axis=0), axis=1) / scale
    dots = np.clip(np.abs(np.sum(quats[order[1:]] * quats[order[:-1]], axis=1)), 0.0, 1.0)
    return float(np.sum(d + 2.0 * np.arccos(dots)))


def greedy_path(centers: np.ndarray, quats: np.ndarray, scale: float, start: int) -> np.ndarray:
    n = len(centers)
    visited = np.zeros(n, dtype=bool)
    order = np.empty(n, dtype=np.int64)
    cur = start
    for k in range(n):
        order[k] = cur
        visited[cur] = True
        if k == n - 1:
            break
        rest = np.flatnonzero(~visited)
        cur = int(rest[np.argmin(step_costs(centers, quats, scale, cur, rest))])
    return order


def nearest_neighbour_order(scene: Scene) -> np.ndarray:
    """A short path through all views: greedy nearest neighbour, O(N^2) time, O(N) memory.

    Started from three candidates (frame 0, the view farthest from the centroid, and the view farthest
    from that one — the ends of an open arc), keeping the shortest; deterministic. -> (N,) frame indices.
    """
    centers, quats, scale = scene.centers(), np.stack([p.qvec for p in scene.poses]), scene.scale()
    far1 = int(np.argmax(np.linalg.norm(centers - centers.mean(0), axis=1)))
    far2 = int(np.argmax(step_costs(centers, quats, scale, far1, np.arange(len(centers)))))
    best, best_len = None, np.inf
    for s in dict.fromkeys([0, far1, far2]):  # ordered, without repeats
        o = greedy_path(centers, quats, scale, s)
        length = path_length(scene, o)
        if length < best_len - 1e-12:
            best, best_len = o, length
    if best is None:  # every length is inf or NaN
        raise InputError(
            f"{scene.source or 'scene'}: camera positions too far apart to plan a path "
            "(distances overflow); check the pose file's translations"
        )
    # Present the path in the direction that agrees with capture order where it can (stable output).
    if best[0] > best[-1]:
        best = best[::-1].copy()
    return best


def plan_order(scene: Scene, order: str = "auto") -> np.ndarray:
    """The sequence along which "consecutive" is meant: (N,) indices into ``scene.frames``. When the file
    names' order (numbers compared as numbers) walks much further than the camera positions' nearest-
    neighbour path, names and positions disagree: a warning says so and "auto" follows the positions."""
    n = len(scene)
    capture = np.arange(n)
    if order not in ("auto", "capture", "nearest"):
        raise ConfigError(f"order must be auto, capture or nearest, got {order!r}")
    if n < 3:
        return capture
    nn = nearest_neighbour_order(scene)
    if order == "nearest":
        return nn
    ratio = path_length(scene, capture) / max(path_length(scene, nn), 1e-12)
    if ratio > AUTO_RATIO:
        log.warning(
            "the file names' order walks %.2fx the path through the nearest cameras: names and camera "
            "positions disagree about the capture order; %s",
            ratio,
            "following the positions (--order capture keeps the names' order)"
            if order == "auto"
            else "keeping the names' order as asked (--order auto follows the positions)",
        )
        return nn if order == "auto" else capture
    return capture


def indices_along(scene: Scene, seq: np.ndarray) -> np.ndarray:
    """Index of each view along the path: the frames' own when monotonic along it, else positions."""
    own = np.array([scene.frames[i].index for i in seq], dtype=np.float64)
    steps = np.diff(own)
    if len(own) < 2 or np.all(steps > 0) or np.all(steps < 0):
        return own
    log.info("frame indices are not monotonic along the path; planned indices count positions along it")
    return np.arange(len(seq), dtype=np.float64)


def reindexed(scene: Scene, seq: np.ndarray) -> Scene:
    """The scene with its frames in path order and each frame's index = the index the plan uses for it.

    Use it with a plan made with ``order="nearest"`` so source and planned frames share one index scale.
    """
    idx = indices_along(scene, np.asarray(seq))
    frames = [replace(scene.frames[i], index=float(k)) for i, k in zip(seq, idx)]
    return replace(scene, frames=frames)
