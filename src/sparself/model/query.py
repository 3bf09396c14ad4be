"""What training and synthesis share: the source views, the queries, and the one call that renders them.

- :class:`Sources`: the source views of a scene as tensors (images, intrinsics, world-to-camera, pose
  vectors, sequence positions), sorted by frame index; built once from a Scene (:meth:`Sources.from_scene`).
- :class:`Queries`: the views to render (intrinsics, world-to-camera, pose vectors, sequence positions),
  each with its *source set* (indices into the sources the decoder reads, any number: the two bracketing ones, then
  the nearest others by camera centre) and optionally
  those sources aligned to it by optical flow. Training queries are the sources themselves, each left
  out of its own sequence and source set (:func:`leave_one_out`); synthesis queries are novel poses
  (:func:`novel_queries`).
- :func:`render`: the LSTM context at each query step, then the decoder. Every decoder takes
  ``(sources, queries, ctx)`` (:mod:`sparself.model.decoders`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from sparself.capture.scene import Scene
from sparself.core.errors import InputError
from sparself.core.geometry import Pose
from sparself.core.warp import flow_pair
from sparself.model.cnn_lstm import CNNLSTM, PoseNorm

Crop = tuple[int, int, int, int]  # (y0, x0, h, w) in pixels of the query's image


def bracket(positions: np.ndarray, q: float, exclude: int = -1) -> tuple[int, int]:
    """The two sources around position q (the previous and the next), or the two nearest on one side
    beyond the ends. positions: (S,) ascending; exclude: a source that may not be used (the target)."""
    ids = [i for i in range(len(positions)) if i != exclude]
    if len(ids) < 2:
        raise InputError("need at least 2 source frames (besides the target) to synthesize a view")
    before = [i for i in ids if positions[i] <= q]
    after = [i for i in ids if positions[i] > q]
    if before and after:
        return before[-1], after[0]
    return (after[0], after[1]) if not before else (before[-1], before[-2])


def query_pair(
    positions: np.ndarray, centres: np.ndarray, q: float, q_centre: np.ndarray, exclude: int = -1
) -> tuple[tuple[int, int], float]:
    """A query's two sources and its fraction t between them (0 at the first, 1 at the second).

    Within the sequence: the bracketing pair (:func:`bracket`) and t from the sequence positions. Beyond
    either end, a closed capture (a ring, a 360-degree loop: the last view sits next to the first) puts
    the query between the last source and the first: that pair is used, with t = d_last / (d_last +
    d_first) from the camera centres, when the far end's source is nearer to the query's camera than the
    second source of the one-sided pair (which would extrapolate); on an open path it is not."""
    pair = bracket(positions, q, exclude)
    ids = [i for i in range(len(positions)) if i != exclude]
    first, last = ids[0], ids[-1]
    if positions[first] <= q <= positions[last]:
        return pair, bracket_fraction(positions, pair, q)
    d = np.linalg.norm(np.asarray(centres, np.float64) - np.asarray(q_centre, np.float64), axis=1)
    other = first if q > positions[last] else last
    if other != pair[1] and d[other] < d[pair[1]]:
        tot = d[last] + d[first]
        return (last, first), float(d[last] / tot) if tot > 0 else 0.5
    return pair, bracket_fraction(positions, pair, q)


def source_set(
    positions: np.ndarray, centres: np.ndarray, q: float, q_centre: np.ndarray, k: int = 2, exclude: int = -1
) -> tuple[int, ...]:
    """A query's k sources: its pair (:func:`query_pair`: the bracketing one, or the last and first of a
    closed capture) first, then the k - 2 others whose camera centres are nearest to the query's (never
    ``exclude``, the target). centres (S, 3)."""
    return query_sources(positions, centres, q, q_centre, k, exclude)[0]


def query_sources(
    positions: np.ndarray, centres: np.ndarray, q: float, q_centre: np.ndarray, k: int = 2, exclude: int = -1
) -> tuple[tuple[int, ...], float]:
    """A query's :func:`source_set` and its fraction t between the set's first two (:func:`query_pair`),
    from one :func:`query_pair`."""
    pair, t = query_pair(positions, centres, q, q_centre, exclude)
    if k <= 2:
        return pair, t
    dist = np.linalg.norm(np.asarray(centres, np.float64) - np.asarray(q_centre, np.float64), axis=1)
    rest = [int(i) for i in np.argsort(dist, kind="stable") if int(i) != exclude and int(i) not in pair]
    return tuple(pair) + tuple(rest[: k - 2]), t


def camera_centres(w2c: torch.Tensor) -> np.ndarray:
    """World positions of cameras from their world-to-camera matrices (T, 4, 4). -> (T, 3)."""
    m = w2c.detach().double().cpu()
    return (-(m[:, :3, :3].transpose(1, 2) @ m[:, :3, 3:4])[..., 0]).numpy()


def bracket_fraction(positions: np.ndarray, pair: tuple[int, ...], q: float) -> float:
    """Position of q between the sources of ``pair``: 0 at the first, 1 at the second."""
    a, b = float(positions[pair[0]]), float(positions[pair[1]])
    return (q - a) / (b - a) if b != a else 0.0


def index_positions(src_index: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Sequence positions (0..S-1 for the sorted sources) of frame indices; fractional in between,
    extrapolated linearly beyond the ends with the end spacing. src_index: (S,) ascending."""
    src_index = np.asarray(src_index, np.float64)
    index = np.atleast_1d(np.asarray(index, np.float64))
    s = len(src_index)
    if s == 1:
        return index - src_index[0]
    pos = np.interp(index, src_index, np.arange(s, dtype=np.float64))
    lo, hi = index < src_index[0], index > src_index[-1]
    pos[lo] = (index[lo] - src_index[0]) / max(src_index[1] - src_index[0], 1e-9)
    pos[hi] = s - 1 + (index[hi] - src_index[-1]) / max(src_index[-1] - src_index[-2], 1e-9)
    return pos


@dataclass
class Sources:
    """Source views sorted by frame index. images (S, 3, H, W) in [0, 1]; K (S, 3, 3) and w2c (S, 4, 4)
    float32; index (S,) their frame indices; poses their Poses; order their positions in the scene's
    frames. Set later: vectors (S, 7) normalised pose vectors (:meth:`posed`), depths (D,) the sweep
    planes, backbone_input and, for a frozen backbone, features (its outputs, computed once)."""

    images: torch.Tensor
    K: torch.Tensor
    w2c: torch.Tensor
    index: np.ndarray
    poses: list[Pose]
    order: np.ndarray
    vectors: torch.Tensor | None = None
    depths: torch.Tensor | None = None
    backbone_input: torch.Tensor | None = None
    features: torch.Tensor | None = None

    @classmethod
    def from_scene(cls, scene: Scene) -> "Sources":
        """The scene's frames (one image size; ValueError otherwise) as tensors at their cameras' size."""
        order = np.argsort([f.index for f in scene.frames], kind="stable")
        imgs = np.stack([scene.load(int(i)) for i in order])
        return cls(
            images=torch.from_numpy(imgs).permute(0, 3, 1, 2).contiguous(),
            K=torch.tensor(np.stack([scene.camera(int(i)).K for i in order]), dtype=torch.float32),
            w2c=torch.tensor(np.stack([scene.frames[int(i)].pose.w2c() for i in order]), dtype=torch.float32),
            index=np.array([scene.frames[int(i)].index for i in order], dtype=np.float64),
            poses=[scene.frames[int(i)].pose for i in order],
            order=order,
        )

    def __len__(self) -> int:
        return int(self.images.shape[0])

    @property
    def device(self) -> torch.device:
        return self.images.device

    @property
    def hw(self) -> tuple[int, int]:
        return int(self.images.shape[-2]), int(self.images.shape[-1])

    @property
    def positions(self) -> np.ndarray:
        """Sequence positions of the sources: 0..S-1."""
        return np.arange(len(self), dtype=np.float64)

    def to(self, device: torch.device) -> "Sources":
        return replace(self, images=self.images.to(device), K=self.K.to(device), w2c=self.w2c.to(device))

    def pose_vectors(self) -> torch.Tensor:
        """``vectors``, which :meth:`posed` sets. -> (S, 7)"""
        if self.vectors is None:
            raise ValueError("sources without pose vectors: call posed() first")
        return self.vectors

    def sweep_depths(self) -> torch.Tensor:
        """``depths``, the sweep planes :meth:`posed` sets. -> (D,)"""
        if self.depths is None:
            raise ValueError("sources without sweep planes: call posed() with depths first")
        return self.depths

    def posed(self, norm: PoseNorm, depths: np.ndarray | None = None) -> "Sources":
        """With the pose vectors of ``norm`` and the sweep planes ``depths`` (on the sources' device)."""
        dev = self.device
        return replace(
            self,
            vectors=torch.from_numpy(norm.vectors(self.poses)).to(dev),
            depths=None if depths is None else torch.tensor(depths, dtype=torch.float32, device=dev),
        )


@dataclass
class Queries:
    """Views to render. K (T, 3, 3), w2c (T, 4, 4), vectors (T, 7) on the sources' device; positions (T,)
    sequence positions among the sources; n_before (T,) sources before each query step in its sequence;
    sets: per query the indices of the sources its decoder reads; hw: output size (h, w); aligned:
    (T, n, 3, H, W) the first n sources of each set aligned to the query by optical flow, or None;
    crops: per query the part of its image to render, or None (whole images); fractions (T,): each
    query's t between the two first sources of its set (:func:`query_pair`; None: from the positions)."""

    K: torch.Tensor
    w2c: torch.Tensor
    vectors: torch.Tensor
    positions: np.ndarray
    n_before: torch.Tensor
    sets: list[tuple[int, ...]]
    hw: tuple[int, int]
    aligned: torch.Tensor | None = None
    crops: list[Crop] | None = None
    fractions: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.sets)

    def select(self, idx) -> "Queries":
        """The queries at positions ``idx`` (a list of ints), in that order."""
        idx = np.asarray(idx)
        return replace(
            self,
            K=self.K[idx],
            w2c=self.w2c[idx],
            vectors=self.vectors[idx],
            positions=self.positions[idx],
            n_before=self.n_before[idx],
            sets=[self.sets[int(i)] for i in idx],
            aligned=None if self.aligned is None else self.aligned[idx],
            crops=None if self.crops is None else [self.crops[int(i)] for i in idx],
            fractions=None if self.fractions is None else self.fractions[idx],
        )

    def cropped(self, crops: list[Crop]) -> "Queries":
        return replace(self, crops=list(crops))

    def crop_camera(self, b: int, crop: Crop) -> torch.Tensor:
        """Intrinsics of query b for the crop (y0, x0, h, w): the principal point shifted by its corner."""
        Kc = self.K[b].clone()
        Kc[0, 2] -= crop[1]
        Kc[1, 2] -= crop[0]
        return Kc


def leave_one_out(sources: Sources, hw: tuple[int, int] | None = None, k: int = 2) -> Queries:
    """Every source as a query, predicted from the others: its own step is the query step in its sequence,
    and its source set is its k sources (:func:`source_set`; never itself). hw: output size (default: the
    sources')."""
    pos, centres = sources.positions, camera_centres(sources.w2c)
    found = [query_sources(pos, centres, float(pos[t]), centres[t], k, exclude=t) for t in range(len(pos))]
    return Queries(
        K=sources.K,
        w2c=sources.w2c,
        vectors=sources.pose_vectors(),
        positions=pos,
        n_before=torch.as_tensor(np.arange(len(pos)), device=sources.device),
        sets=[s for s, _ in found],
        hw=hw or sources.hw,
        fractions=np.array([t for _, t in found], np.float64),
    )


def novel_queries(
    sources: Sources, K: np.ndarray, w2c: np.ndarray, vectors: np.ndarray, index, hw: tuple[int, int], k: int = 2
) -> Queries:
    """Queries at new poses with fractional frame indices ``index`` among the sources' indices; each
    query step sits after every source at or before it, and its source set is its k sources
    (:func:`source_set`). K (T, 3, 3), w2c (T, 4, 4), vectors (T, 7) arrays."""
    if len(sources) < 2:
        raise InputError("need at least 2 source frames to synthesize")
    dev, src_pos = sources.device, sources.positions
    q_pos = index_positions(sources.index, index)
    w2c_t = torch.tensor(w2c, dtype=torch.float32, device=dev)
    centres, q_centres = camera_centres(sources.w2c), camera_centres(w2c_t)
    found = [query_sources(src_pos, centres, float(q), c, k) for q, c in zip(q_pos, q_centres)]
    return Queries(
        K=torch.tensor(K, dtype=torch.float32, device=dev),
        w2c=w2c_t,
        vectors=torch.from_numpy(vectors).to(dev),
        positions=q_pos,
        n_before=torch.as_tensor(np.searchsorted(src_pos, q_pos, side="right"), device=dev),
        sets=[s for s, _ in found],
        hw=hw,
        fractions=np.array([t for _, t in found], np.float64),
    )


def flow_aligned(sources: Sources, queries: Queries) -> Queries:
    """The queries with the first two sources of each set aligned to it by optical flow
    (:func:`sparself.core.warp.flow_pair`, at the query's position between them, clipped to [-0.5, 1.5])."""
    imgs = sources.images.float().permute(0, 2, 3, 1).cpu().numpy()
    out = []
    for b, (s, q) in enumerate(zip(queries.sets, queries.positions)):
        t = bracket_fraction(sources.positions, s[:2], float(q)) if queries.fractions is None else queries.fractions[b]
        out.append(np.stack(flow_pair(imgs[s[0]], imgs[s[1]], float(np.clip(t, -0.5, 1.5)))))
    aligned = torch.from_numpy(np.stack(out)).permute(0, 1, 4, 2, 3).to(sources.device).contiguous()
    return replace(queries, aligned=aligned)


def contexts(model: CNNLSTM, sources: Sources, queries: Queries) -> torch.Tensor:
    """The LSTM output at each query step. -> (T, 512)."""
    if sources.features is not None:  # a frozen backbone: its outputs were computed once
        feats = model.feat_fc(sources.features)
    else:
        bb = sources.backbone_input if sources.backbone_input is not None else model.backbone_input(sources.images)
        feats = model.encode(bb)
    src_pos = torch.tensor(sources.positions, dtype=torch.float32, device=sources.device)
    q_pos = torch.tensor(queries.positions, dtype=torch.float32, device=sources.device)
    return model.contexts(feats, sources.pose_vectors(), src_pos, queries.vectors, q_pos, queries.n_before)


def render(model: CNNLSTM, sources: Sources, queries: Queries, crops: list[Crop] | None = None) -> torch.Tensor:
    """The queries' images (or their ``crops``) rendered from the sources. -> (T, 3, h, w), the decoder's
    output before clamping; training and synthesis both call this."""
    if crops is not None:
        queries = queries.cropped(crops)
    return model.decoder(sources, queries, contexts(model, sources, queries))


def render_with_confidence(model: CNNLSTM, sources: Sources, queries: Queries) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`render` of whole images plus each pixel's confidence in [0, 1] (the decoder's
    ``with_confidence``). -> ((T, 3, h, w), (T, 1, h, w))."""
    return model.decoder.with_confidence(sources, queries, contexts(model, sources, queries))
