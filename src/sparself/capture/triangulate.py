"""Sparse 3D points triangulated from a posed scene's real photos at their KNOWN poses (no pose estimation).

Why: a capture's own sparse points (e.g. a published COLMAP model) were triangulated from every photo,
held-out ones included, and captures with poses but no points (LLFF ``poses_bounds.npy``) have none.
The evaluation triangulates the N inputs' photos instead, so the reconstructors start from points that
only the inputs saw.

Method (OpenCV): SIFT features at a bounded size (long side <= ``max_side``), each frame matched with its
``neighbours`` nearest frames by camera centre (Lowe ratio test + mutual check), each match triangulated
(DLT, ``cv2.triangulatePoints``) and kept only if in front of both cameras, reprojected within
``max_error`` pixels in both and seen under at least ``min_angle`` degrees. Matches sharing a keypoint
are chained into tracks (one point per track: the mean of its pairs' points; a track that holds two
keypoints of one frame is dropped as inconsistent). Deterministic: OpenCV runs on one thread here.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from sparself.capture.scene import MIN_POINTS, Camera, Observations, Scene, points_depth_range

log = logging.getLogger(__name__)


@dataclass
class TriangulateConfig:
    """max_side: long side in px of the images features are found in (smaller photos keep their size);
    neighbours: frames each frame is matched with (nearest camera centres); features: SIFT features per
    image; ratio: Lowe's ratio test; max_error: reprojection error in px at the working size; min_angle:
    degrees between the two rays of a match."""

    max_side: int = 800
    neighbours: int = 4
    features: int = 4000
    ratio: float = 0.8
    max_error: float = 2.0
    min_angle: float = 1.5


@dataclass
class Triangulated:
    """points: (P, 3) float64 world points; colors: (P, 3) in [0, 1] (mean of the observed pixels).
    views: frames used; pairs: frame pairs matched; matches: matches passing the ratio and mutual tests;
    kept: pairwise triangulations passing the geometric checks; seconds: wall time; observations: each
    frame's keypoints in the points' tracks, by frame name (``Scene.observations``: what a written
    COLMAP model keeps as its tracks, instead of projecting every point into every view)."""

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    observations: dict[str, Observations] = field(default_factory=dict)
    views: int = 0
    pairs: int = 0
    matches: int = 0
    kept: int = 0
    seconds: float = 0.0

    def summary(self) -> str:
        return (
            f"{len(self.points)} points from {self.views} views ({self.pairs} pairs, {self.matches} matches, "
            f"{self.kept} triangulated) in {self.seconds:.1f} s"
        )


@dataclass
class _View:
    """One frame at the working size: camera, (3, 4) projection, centre, keypoints (K, 2) in the
    pixel-corner convention, descriptors (K, 128) and the image (H, W, 3) for colours."""

    cam: Camera
    P: np.ndarray
    center: np.ndarray
    xy: np.ndarray
    desc: np.ndarray
    image: np.ndarray


def real_frames(scene: Scene) -> list[int]:
    """Indices of the frames with a real photo (not synthetic, with a path or an in-memory image)."""
    return [i for i, f in enumerate(scene.frames) if not f.synthetic and (f.path is not None or f.image is not None)]


def _view(scene: Scene, i: int, cfg: TriangulateConfig, sift) -> _View:
    import cv2

    cam = scene.camera(i)
    s = min(1.0, cfg.max_side / max(cam.width, cam.height))
    if s < 1.0:
        cam = cam.resized(max(1, round(cam.width * s)), max(1, round(cam.height * s)))
    img = scene.image(i, (cam.width, cam.height))
    gray = cv2.cvtColor(np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    kps, desc = sift.detectAndCompute(gray, None)
    xy = np.array([k.pt for k in kps], np.float64).reshape(-1, 2) + 0.5  # OpenCV: pixel centres at integers
    pose = scene.frames[i].pose
    P = cam.K @ np.hstack([pose.R, pose.tvec.reshape(3, 1)])
    desc = desc if desc is not None else np.zeros((0, 128), np.float32)
    return _View(cam, P, pose.center, xy, desc, img)


def _pairs(centers: np.ndarray, k: int) -> list[tuple[int, int]]:
    """Unordered pairs (a < b): each view with its k nearest views by camera centre (stable ties)."""
    d = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
    out = set()
    for a in range(len(centers)):
        for b in np.argsort(d[a], kind="stable")[1 : k + 1]:
            out.add((min(a, int(b)), max(a, int(b))))
    return sorted(out)


def _match(da: np.ndarray, db: np.ndarray, ratio: float) -> np.ndarray:
    """(M, 2) index pairs (into da, db) passing the ratio test both ways and the mutual check."""
    import cv2

    if len(da) < 2 or len(db) < 2:
        return np.zeros((0, 2), int)
    bf = cv2.BFMatcher(cv2.NORM_L2)

    def best(x, y) -> np.ndarray:  # y index of each x's ratio-passing match, -1 if none
        out = np.full(len(x), -1)
        for m in bf.knnMatch(x, y, k=2):
            if len(m) == 2 and m[0].distance < ratio * m[1].distance:
                out[m[0].queryIdx] = m[0].trainIdx
        return out

    ab, ba = best(da, db), best(db, da)
    a = np.flatnonzero(ab >= 0)
    a = a[ba[ab[a]] == a]
    return np.stack([a, ab[a]], 1)


def _triangulate_pair(va: _View, vb: _View, m: np.ndarray, cfg: TriangulateConfig) -> tuple[np.ndarray, np.ndarray]:
    """(M', 3) points of the matches ``m`` that pass the checks, and the mask (M,) of those."""
    import cv2

    xa, xb = va.xy[m[:, 0]], vb.xy[m[:, 1]]
    X = cv2.triangulatePoints(va.P, vb.P, xa.T, xb.T)
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (X[:3] / X[3]).T
    ok = np.all(np.isfinite(X), axis=1)
    for v, x in ((va, xa), (vb, xb)):
        p = np.hstack([X, np.ones((len(X), 1))]) @ v.P.T
        with np.errstate(divide="ignore", invalid="ignore"):
            err = np.linalg.norm(p[:, :2] / p[:, 2:] - x, axis=1)
        depth = p[:, 2] / np.linalg.norm(v.P[2, :3])
        ok &= (depth > 0) & (err <= cfg.max_error)
    ra, rb = X - va.center, X - vb.center
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.sum(ra * rb, 1) / (np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1))
    ok &= np.degrees(np.arccos(np.clip(cos, -1, 1))) >= cfg.min_angle
    return X[ok], ok


def _tracks(views: list[_View], nodes: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One point per track. nodes: (E, 2) global keypoint ids of each kept match; pts: (E, 3) its point.
    -> (P, 3) points (mean over the track's matches), (P, 3) colours (mean over its keypoints' pixels),
    (K, 3) int (view, point, keypoint index in the view) of the kept tracks' keypoints."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    offsets = np.cumsum([0] + [len(v.xy) for v in views])
    graph = coo_matrix((np.ones(len(nodes)), (nodes[:, 0], nodes[:, 1])), shape=(offsets[-1],) * 2)
    _, label = connected_components(graph, directed=False)
    used = np.unique(nodes)
    view_of = np.searchsorted(offsets, used, side="right") - 1
    tracks, lab = np.unique(label[used], return_inverse=True)
    # a track holding two keypoints of one view chained inconsistent matches: drop it
    per_view = np.unique(np.stack([lab, view_of], 1), axis=0)[:, 0]
    good = np.bincount(lab, minlength=len(tracks)) == np.bincount(per_view, minlength=len(tracks))
    edge = np.searchsorted(tracks, label[nodes[:, 0]])
    n_edges = np.bincount(edge, minlength=len(tracks))
    points = np.stack([np.bincount(edge, pts[:, d], len(tracks)) for d in range(3)], 1) / n_edges[:, None]
    colors = np.zeros((len(used), 3))
    for v in np.unique(view_of):
        sel = view_of == v
        xy = views[v].xy[used[sel] - offsets[v]]
        h, w = views[v].image.shape[:2]
        colors[sel] = views[v].image[np.clip(xy[:, 1].astype(int), 0, h - 1), np.clip(xy[:, 0].astype(int), 0, w - 1)]
    cols: np.ndarray = np.stack([np.bincount(lab, colors[:, d], len(tracks)) for d in range(3)], 1)  # float sums
    cols /= np.bincount(lab, minlength=len(tracks))[:, None]
    keep = good[lab]
    members = np.stack([view_of, np.cumsum(good)[lab] - 1, used - offsets[view_of]], 1)[keep]
    return points[good], np.clip(cols[good], 0.0, 1.0), members


def _observations(scene: Scene, idx: list[int], views: list[_View], members: np.ndarray) -> dict[str, Observations]:
    """The tracks' keypoints by frame name (xy at the working size, which ``size`` records)."""
    out = {}
    for v in np.unique(members[:, 0]):
        m = members[members[:, 0] == v]
        cam = views[v].cam
        out[scene.frames[idx[v]].name] = Observations(
            m[:, 1].astype(np.int64), views[v].xy[m[:, 2]], (cam.width, cam.height)
        )
    return out


def _pairwise(
    views: list[_View], pairs: list[tuple[int, int]], cfg: TriangulateConfig, out: Triangulated
) -> tuple[np.ndarray, np.ndarray]:
    """Match and triangulate every pair. -> (E, 2) global keypoint ids of the kept matches, (E, 3) points."""
    offsets = np.cumsum([0] + [len(v.xy) for v in views])
    nodes, pts = [np.zeros((0, 2), int)], [np.zeros((0, 3))]
    for a, b in pairs:
        m = _match(views[a].desc, views[b].desc, cfg.ratio)
        out.matches += len(m)
        if len(m) == 0:
            continue
        X, ok = _triangulate_pair(views[a], views[b], m, cfg)
        nodes.append(m[ok] + [offsets[a], offsets[b]])
        pts.append(X)
    return np.concatenate(nodes), np.concatenate(pts)


def triangulate(scene: Scene, config: TriangulateConfig | None = None) -> Triangulated:
    """Sparse points of ``scene`` from its real photos at their known poses (synthetic frames and frames
    without a photo are skipped). Fewer than 2 such frames, or no match passing the checks: no points
    (logged). Returns :class:`Triangulated` (points (P, 3), colours (P, 3) and counts)."""
    import cv2

    cfg = config or TriangulateConfig()
    t0 = time.perf_counter()
    idx = real_frames(scene)
    out = Triangulated(views=len(idx))
    if len(idx) < 2:
        log.warning("triangulation: %d real photo(s); at least 2 are needed, no points", len(idx))
        return out
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one thread: the same matches every run
    try:
        # cv2's type stubs lack this function
        sift = cv2.SIFT_create(nfeatures=cfg.features)  # type: ignore[attr-defined]
        views = [_view(scene, i, cfg, sift) for i in idx]
        pairs = _pairs(np.stack([v.center for v in views]), cfg.neighbours)
        out.pairs = len(pairs)
        nodes, pts = _pairwise(views, pairs, cfg, out)
    finally:
        cv2.setNumThreads(threads)
    out.kept = len(pts)
    if len(pts):
        out.points, out.colors, members = _tracks(views, nodes, pts)
        out.observations = _observations(scene, idx, views, members)
    out.seconds = time.perf_counter() - t0
    (log.info if len(out.points) else log.warning)("triangulation: %s", out.summary())
    return out


def with_points(scene: Scene, tri: Triangulated) -> Scene:
    """``scene`` with the triangulated points, their colours (uint8 ``point_colors``, as the
    COLMAP and PLY writers read them) and tracks (``observations``), replacing the scene's own."""
    colors = np.round(tri.colors * 255).astype(np.uint8)
    return replace(scene, points=tri.points, point_colors=colors, observations=dict(tri.observations))


def ensure_points(scene: Scene, photos: Scene | None = None, config: TriangulateConfig | None = None) -> Scene:
    """``scene`` unchanged if it has MIN_POINTS sparse points or more, else with points triangulated from
    the real photos of ``photos`` (default ``scene``; its synthetic frames are never used) when that gives
    MIN_POINTS or more; otherwise ``scene`` unchanged (logged) except that a scene with neither bounds nor
    points to bound its depth takes the triangulated points' depth range as its bounds."""
    if scene.points is not None and len(scene.points) >= MIN_POINTS:
        return scene
    tri = triangulate(scene if photos is None else photos, config)
    if len(tri.points) < MIN_POINTS:
        own = 0 if scene.points is None else len(scene.points)
        log.warning(
            "%d points triangulated from %d photos (< %d): not used, the scene is written %s",
            len(tri.points),
            tri.views,
            MIN_POINTS,
            f"with its own {own}" if own else "without points",
        )
        seen = points_depth_range(tri.points, scene.poses)
        if (
            seen
            and scene.bounds is None
            and (scene.points is None or not points_depth_range(scene.points, scene.poses))
        ):
            return replace(scene, bounds=seen)  # still better than a guess from the camera layout
        return scene
    log.info(
        "triangulated %d points from %d photos at their known poses (%.1f s)", len(tri.points), tri.views, tri.seconds
    )
    return with_points(scene, tri)
