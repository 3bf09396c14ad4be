"""Classical view-synthesis baselines, all with the synthesizer call the network shares

    fn(scene: Scene, targets: list[Frame], **cfg) -> np.ndarray (T, H, W, 3) float32 in [0, 1]

``scene`` holds the source frames (images reachable through ``scene.load``); ``targets`` give pose,
camera_id and fractional ``index``. A baseline never reads a target's image (``path``/``image`` are
ignored). Each output has its target camera's size.

- ``nearest``: the source with the closest pose (see :func:`pose_distance`), resized to the target camera.
- ``blend``: ``(1 - t) I_a + t I_b`` of the two bracketing sources (see :func:`bracketing`).
- ``flow``: OpenCV DIS optical flow between the two bracketing sources; both are backward-warped to the
  target's fractional position t with the Super-SloMo flow approximation and blended ``(1 - t), t``.
- ``planesweep``: the k nearest sources (bracketing pair first) are plane-swept into the target camera
  over planes uniform in disparity between the scene's depth bounds; each pixel takes the plane with the
  lowest photo-consistency cost (variance across warped sources, box-filtered), colour = weighted mean
  of the valid warped sources at that plane.

Neighbour choice. "Bracketing" sources of a target with fractional index x are the sources with the
largest index <= x and the smallest index >= x (t = (x - i_a) / (i_b - i_a)). When indices cannot be
used (non-finite, duplicated among sources, or x outside the sources' range) the two nearest sources by
:func:`pose_distance` are used instead, with t = d_a / (d_a + d_b).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from sparself.capture.images import resize_image
from sparself.capture.scene import Frame, Scene
from sparself.core.geometry import inverse_depth_planes, rotation_angle_deg
from sparself.core.warp import flow_pair, plane_sweep
from sparself.model.query import bracket

log = logging.getLogger(__name__)


# ---- neighbour selection -----------------------------------------------------------------------


def pose_distance(scene: Scene, pose, rot_weight: float = 1.0) -> np.ndarray:
    """Distance of a pose to every source pose of ``scene``. -> (N,).

    ``||C - C_i|| / scene.scale() + rot_weight * angle(R, R_i)`` with the angle in radians: one scene
    scale (median camera distance to the rig's centroid) of translation counts as much as one radian
    of rotation, so the measure does not depend on the capture's units.
    """
    c = scene.centers()
    d = np.linalg.norm(c - pose.center[None], axis=1) / scene.scale()
    Rs = np.stack([f.pose.R for f in scene.frames])
    ang = np.radians(rotation_angle_deg(Rs, np.broadcast_to(pose.R, Rs.shape)))
    return d + rot_weight * ang


def nearest_sources(scene: Scene, pose, k: int, rot_weight: float = 1.0) -> np.ndarray:
    """Indices (into scene.frames) of the k sources closest to ``pose``, nearest first. -> (min(k, N),)."""
    return np.argsort(pose_distance(scene, pose, rot_weight), kind="stable")[:k]


def _indices_usable(scene: Scene) -> bool:
    idx = np.array([f.index for f in scene.frames], dtype=np.float64)
    return bool(np.all(np.isfinite(idx)) and len(np.unique(idx)) == len(idx))


def bracketing(scene: Scene, target: Frame, rot_weight: float = 1.0) -> tuple[int, int, float]:
    """(a, b, t): the two sources around ``target`` and its fractional position t in [0, 1] from a to b.

    By index when the indices are usable and the target's index lies within the sources' range,
    otherwise the two nearest by pose (t = d_a / (d_a + d_b)). With one source: (0, 0, 0.0).
    """
    n = len(scene.frames)
    if n == 0:
        raise ValueError("scene has no source frames")
    if n == 1:
        return 0, 0, 0.0
    x = float(target.index)
    idx = np.array([f.index for f in scene.frames], dtype=np.float64)
    if _indices_usable(scene) and np.isfinite(x) and idx.min() <= x <= idx.max():
        hit = np.flatnonzero(idx == x)
        if len(hit):  # the target sits on a source
            return int(hit[0]), int(hit[0]), 0.0
        order = np.argsort(idx, kind="stable")
        i, j = bracket(idx[order], x)  # the same rule as the network's source sets
        a, b = int(order[i]), int(order[j])
        return a, b, float((x - idx[a]) / (idx[b] - idx[a]))
    d = pose_distance(scene, target.pose, rot_weight)
    a, b = (int(i) for i in np.argsort(d, kind="stable")[:2])
    t = float(d[a] / (d[a] + d[b])) if d[a] + d[b] > 0 else 0.0
    return a, b, t


def _source(scene: Scene, i: int, size: tuple[int, int]) -> np.ndarray:
    """Source image i at size (W, H)."""
    img = scene.load(i)
    if (img.shape[1], img.shape[0]) != tuple(size):
        img = resize_image(img, size)
    return img


def _target_size(scene: Scene, target: Frame) -> tuple[int, int]:
    cam = scene.cameras[target.camera_id]
    return cam.width, cam.height


# ---- baselines ---------------------------------------------------------------------------------


def nearest(scene: Scene, targets: list[Frame], rot_weight: float = 1.0, **_) -> np.ndarray:
    """The closest source by :func:`pose_distance`, at each target's size. -> (T, H, W, 3)."""
    out = []
    for tg in targets:
        i = int(nearest_sources(scene, tg.pose, 1, rot_weight)[0])
        out.append(_source(scene, i, _target_size(scene, tg)))
    return np.stack(out).astype(np.float32)


def blend(scene: Scene, targets: list[Frame], rot_weight: float = 1.0, **_) -> np.ndarray:
    """Linear blend ``(1 - t) I_a + t I_b`` of the bracketing sources. -> (T, H, W, 3)."""
    out = []
    for tg in targets:
        a, b, t = bracketing(scene, tg, rot_weight)
        size = _target_size(scene, tg)
        out.append((1.0 - t) * _source(scene, a, size) + t * _source(scene, b, size))
    return np.clip(np.stack(out), 0.0, 1.0).astype(np.float32)


def flow(scene: Scene, targets: list[Frame], rot_weight: float = 1.0, **_) -> np.ndarray:
    """Optical-flow interpolation between the bracketing sources. -> (T, H, W, 3).

    With F01, F10 the flows between the neighbours, the flows from the intermediate frame are
    approximated as F_t0 = -(1-t) t F01 + t^2 F10 and F_t1 = (1-t)^2 F01 - t (1-t) F10 (Jiang et al.,
    Super SloMo, 2018; :func:`sparself.core.warp.flow_pair`); the result is (1-t) I0(x + F_t0) + t I1(x + F_t1).
    """
    out = []
    for tg in targets:
        a, b, t = bracketing(scene, tg, rot_weight)
        size = _target_size(scene, tg)
        i0, i1 = _source(scene, a, size), _source(scene, b, size)
        if a == b or t in (0.0, 1.0):
            out.append(i0 if t < 0.5 else i1)
            continue
        w0, w1 = flow_pair(i0, i1, t)
        out.append((1 - t) * w0 + t * w1)
    return np.clip(np.stack(out), 0.0, 1.0).astype(np.float32)


@dataclass
class PlaneSweepConfig:
    """num_planes: depth planes uniform in disparity over ``scene.depth_bounds()``; k: sources per target;
    box: side of the box filter on the cost (odd); rot_weight: see :func:`pose_distance`."""

    num_planes: int = 32
    k: int = 2
    box: int = 5
    rot_weight: float = 1.0


def _sources_for(scene: Scene, tg: Frame, k: int, rot_weight: float) -> tuple[list[int], list[float]]:
    """The bracketing pair (weights 1-t, t) then further nearest sources (weight 0.5 / rank)."""
    a, b, t = bracketing(scene, tg, rot_weight)
    idx, w = [a], [1.0 - t]
    if b != a:
        idx.append(b)
        w.append(t)
    for j in nearest_sources(scene, tg.pose, len(scene.frames), rot_weight):
        if len(idx) >= k:
            break
        if int(j) not in idx:
            idx.append(int(j))
            w.append(0.5 / len(idx))
    w = np.maximum(np.asarray(w), 1e-3)  # a source exactly at the target still counts
    return idx, list(w / w.sum())


def planesweep(scene: Scene, targets: list[Frame], **cfg) -> np.ndarray:
    """Plane-sweep depth warping of the k nearest sources into each target. -> (T, H, W, 3).

    cfg: fields of :class:`PlaneSweepConfig`. Pixels where no plane is seen by two sources take the
    weighted colour of whatever source sees them (else black).
    """
    c = PlaneSweepConfig(**{k: v for k, v in cfg.items() if k in PlaneSweepConfig.__dataclass_fields__})
    near, far = scene.depth_bounds()
    depths = inverse_depth_planes(near, far, c.num_planes)
    out = []
    for tg in targets:
        cam = scene.cameras[tg.camera_id]
        hw = (cam.height, cam.width)
        idx, w = _sources_for(scene, tg, max(1, c.k), c.rot_weight)
        src = torch.from_numpy(np.stack([scene.load(i).transpose(2, 0, 1) for i in idx])).float()
        Ks = np.stack([scene.camera(i).K for i in idx])
        w2cs = np.stack([scene.frames[i].pose.w2c() for i in idx])
        wts = torch.tensor(w, dtype=torch.float32).view(-1, 1, 1, 1, 1)
        best_cost = torch.full((1, 1) + hw, float("inf"))
        best_col = torch.zeros((3,) + hw)
        any_col = torch.zeros((3,) + hw)
        any_set = torch.zeros((1,) + hw, dtype=torch.bool)
        chunk = max(1, int(4e6 // (len(idx) * 3 * hw[0] * hw[1])))  # planes per sweep: bounded memory
        for d0 in range(0, len(depths), chunk):
            vol, valid = plane_sweep(src, Ks, w2cs, cam.K, tg.pose.w2c(), depths[d0 : d0 + chunk], hw)
            wv = wts * valid  # (S, D, 1, H, W)
            wsum = wv.sum(0)
            col = (wv * vol).sum(0) / wsum.clamp_min(1e-8)  # (D, 3, H, W)
            cnt = valid.sum(0)
            mean = (valid * vol).sum(0) / cnt.clamp_min(1)
            var = ((valid * (vol - mean) ** 2).sum(0) / cnt.clamp_min(1)).mean(1, keepdim=True)
            cost = F.avg_pool2d(var, c.box, 1, c.box // 2, count_include_pad=False)
            cost = torch.where(cnt >= min(2, len(idx)), cost, torch.full_like(cost, float("inf")))
            cmin, arg = cost.min(0)  # (1, H, W): first (nearest) plane on ties
            ccol = torch.gather(col, 0, arg[None].expand(1, 3, *hw))[0]
            better = cmin < best_cost[0]
            best_cost[0] = torch.where(better, cmin, best_cost[0])
            best_col = torch.where(better, ccol, best_col)
            seen = wsum > 0  # (D, 1, H, W)
            first = torch.gather(col, 0, seen.to(torch.uint8).argmax(0, keepdim=True).expand(1, 3, *hw))[0]
            fill = seen.any(0) & ~any_set
            any_col = torch.where(fill, first, any_col)
            any_set |= fill
        res = torch.where(torch.isfinite(best_cost[0]), best_col, any_col)
        out.append(res.permute(1, 2, 0).numpy())
    return np.clip(np.stack(out), 0.0, 1.0).astype(np.float32)


BASELINES = {"nearest": nearest, "blend": blend, "flow": flow, "planesweep": planesweep}
