"""The paper's CNN–LSTM (section 3.3): ResNet-18 features -> FC 512, pose embedding Linear(7 -> 128),
fixed sinusoidal encoding (512) of the frame index, concatenated (1152) into a 2-layer LSTM (hidden 512),
whose output at a *query step* conditions an image decoder.

Leakage-free sequences: the frame to predict never contributes an image. Its step in the sequence is a
query step: its pose, its (possibly fractional) index, and a learned "no image" feature vector in place of
the CNN feature. Training predicts each training frame from the others this way (leave-one-out); novel
poses at inference are query steps inserted among all source frames at fractional indices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from sparself.core.geometry import Pose
from sparself.model.backbone import IMAGENET_MEAN, IMAGENET_STD, ResNet18

FEAT_DIM, POSE_DIM, PE_DIM, HIDDEN = 512, 128, 512, 512


def positional_encoding(pos: torch.Tensor, dim: int = PE_DIM) -> torch.Tensor:
    """Transformer sinusoids of (fractional) positions: PE(p, 2i) = sin(p / 10000^(2i/d)),
    PE(p, 2i+1) = cos(p / 10000^(2i/d)). pos: (...) float -> (..., dim)."""
    i = torch.arange(0, dim, 2, dtype=torch.float32, device=pos.device)
    freq = torch.exp(-math.log(10000.0) * i / dim)  # (dim/2,)
    ang = pos.float()[..., None] * freq
    out = torch.stack([torch.sin(ang), torch.cos(ang)], dim=-1)  # interleave sin, cos
    return out.reshape(*pos.shape, dim)


@dataclass(frozen=True)
class PoseNorm:
    """How poses become the network's 7-vectors, fixed at training time and stored with the run.

    The world is translated so that ``center`` (the mean training camera centre) is the origin and scaled
    by ``1 / scale`` (``Scene.scale()``: the median distance of the training camera centres to their mean),
    then each COLMAP world-to-camera pose gives ``[tx, ty, tz, qw, qx, qy, qz]`` with
    ``t = -R (C - center) / scale`` and the quaternion's sign chosen so that ``qw >= 0``.
    """

    center: tuple[float, float, float]
    scale: float

    def vector(self, pose: Pose) -> np.ndarray:
        """(7,) float32 network input for a pose."""
        t = -pose.R @ (pose.center - np.asarray(self.center)) / self.scale
        q = pose.qvec if pose.qvec[0] >= 0 else -pose.qvec
        return np.concatenate([t, q]).astype(np.float32)

    def vectors(self, poses) -> np.ndarray:
        """(N, 7) for a list of poses."""
        return np.stack([self.vector(p) for p in poses]) if len(poses) else np.zeros((0, 7), np.float32)


def sequence_layout(n_src: int, src_pos: np.ndarray, q_pos: np.ndarray, exclude: np.ndarray) -> np.ndarray:
    """Order of the steps of one sequence per query: sources (sorted by position) minus ``exclude[b]``,
    with the query step (-1) inserted after every source whose position is <= the query's.

    src_pos: (S,) ascending; q_pos: (B,); exclude: (B,) source id to drop (its image is the target), or -1.
    Returns (B, L) int64 of source ids, -1 at the query step. L = S + 1 - (exclude >= 0); all rows share L.
    """
    rows = []
    for b in range(len(q_pos)):
        keep = [i for i in range(n_src) if i != exclude[b]]
        p = int(np.sum(src_pos[keep] <= q_pos[b]))
        rows.append(keep[:p] + [-1] + keep[p:])
    lens = {len(r) for r in rows}
    if len(lens) > 1:
        raise ValueError("mixing leave-one-out and novel queries in one batch gives ragged sequences")
    return np.asarray(rows, dtype=np.int64).reshape(len(q_pos), -1)


class Decoder(nn.Module):
    """What :class:`CNNLSTM` asks of its image decoder (:mod:`sparself.model.decoders`): called with the
    sources, the queries (:mod:`sparself.model.query`) and the LSTM context ``ctx`` (T, 512), it renders
    the queries (T, 3, h, w)."""

    reads_sources: ClassVar[bool]  # whether it samples the source images (else it decodes the context alone)

    def native_hw(self, hw: tuple[int, int]) -> tuple[int, int]:
        """The size it renders queries of size ``hw`` at (training compares at this size)."""
        raise NotImplementedError

    def with_confidence(self, sources: Any, queries: Any, ctx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The rendered queries and each pixel's confidence in [0, 1]. -> ((T, 3, h, w), (T, 1, h, w))."""
        raise NotImplementedError


class CNNLSTM(nn.Module):
    """The CNN–LSTM context network plus a decoder.

    backbone_size: side of the square backbone input (the paper: 224).
    context: if False the LSTM output given to the decoder is zeroed (ablation: "no LSTM context").
    """

    mean: torch.Tensor  # buffers, registered in __init__
    std: torch.Tensor

    def __init__(self, decoder: Decoder, backbone_size: int = 224, context: bool = True) -> None:
        super().__init__()
        self.backbone = ResNet18()
        self.feat_fc = nn.Linear(512, FEAT_DIM)
        self.query_feature = nn.Parameter(torch.zeros(FEAT_DIM))  # the "no image" feature of a query step
        self.pose_embed = nn.Linear(7, POSE_DIM)
        self.lstm = nn.LSTM(FEAT_DIM + PE_DIM + POSE_DIM, HIDDEN, num_layers=2, batch_first=True)
        self.decoder = decoder
        self.backbone_size = int(backbone_size)
        self.context = bool(context)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def backbone_input(self, images: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) in [0, 1] -> (N, 3, s, s) resized (area-like) and ImageNet-normalised; channels-last
        on CUDA, where the convolutions then run in NHWC (faster on tensor cores)."""
        s = self.backbone_size
        x = F.interpolate(images, size=(s, s), mode="bilinear", align_corners=False, antialias=True)
        x = (x - self.mean) / self.std
        return x.contiguous(memory_format=torch.channels_last) if x.is_cuda else x

    def encode(self, bb_input: torch.Tensor) -> torch.Tensor:
        """(N, 3, s, s) backbone input -> (N, 512) projected CNN features."""
        return self.feat_fc(self.backbone(bb_input))

    def _step(self, x: torch.Tensor, state: list[tuple[torch.Tensor, torch.Tensor]]):
        """One time step of the 2-layer LSTM with nn.LSTM's own weights (gate order i, f, g, o).
        x: (B, 1152); state: per layer (h, c) each (B, 512). -> (top h (B, 512), new state)."""
        new = []
        for layer, (h, c) in enumerate(state):
            gates = F.linear(
                x, getattr(self.lstm, f"weight_ih_l{layer}"), getattr(self.lstm, f"bias_ih_l{layer}")
            ) + F.linear(h, getattr(self.lstm, f"weight_hh_l{layer}"), getattr(self.lstm, f"bias_hh_l{layer}"))
            i, f, g, o = gates.chunk(4, dim=1)
            c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
            h = torch.sigmoid(o) * torch.tanh(c)
            new.append((h, c))
            x = h
        return x, new

    def step_input(self, feat: torch.Tensor, vec: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        """The 1152-d LSTM input: [CNN feature 512 | positional encoding 512 | pose embedding 128]."""
        return torch.cat([feat, positional_encoding(pos).to(feat.dtype), self.pose_embed(vec)], dim=-1)

    def source_states(self, x_src: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Both layers' (h, c) after every prefix of the source sequence, fast path.

        Each layer's h sequence comes from torch's fused LSTM (one call, no Python loop per step); the
        cell states, which it does not return, are recomputed from it: the gates of all steps are one
        matrix product of the inputs and the previous h's, and c_t = f_t * c_{t-1} + i_t * g_t is an
        elementwise scan. The recomputed c equals the LSTM's own c as a function of the weights, so its
        gradient is exact too. :meth:`source_states_reference` is the plain step-by-step version.

        x_src: (S, 1152) step inputs. -> H, C: (S + 1, 2, 512), row k = state after the first k sources.
        """
        s = x_src.shape[0]
        zeros = x_src.new_zeros(1, 2, HIDDEN)
        if s == 0:
            return zeros, zeros
        x = x_src
        hs, cs = [], []
        for layer in range(2):
            w_ih, w_hh = getattr(self.lstm, f"weight_ih_l{layer}"), getattr(self.lstm, f"weight_hh_l{layer}")
            b_ih, b_hh = getattr(self.lstm, f"bias_ih_l{layer}"), getattr(self.lstm, f"bias_hh_l{layer}")
            h, _, _ = torch.lstm(
                x[None],
                (x.new_zeros(1, 1, HIDDEN), x.new_zeros(1, 1, HIDDEN)),
                (w_ih, w_hh, b_ih, b_hh),
                True,
                1,
                0.0,
                self.training,
                False,
                True,
            )
            h = h[0]
            h_prev = torch.cat([h.new_zeros(1, HIDDEN), h[:-1]])
            gates = F.linear(x, w_ih, b_ih) + F.linear(h_prev, w_hh, b_hh)
            gates = gates.to(torch.promote_types(gates.dtype, torch.float32))  # the scan in >= fp32 under autocast
            i, f, g, _o = gates.chunk(4, dim=1)
            f, u = torch.sigmoid(f), torch.sigmoid(i) * torch.tanh(g)
            c_k, c = gates.new_zeros(HIDDEN), []
            for k in range(s):
                c_k = f[k] * c_k + u[k]
                c.append(c_k)
            hs.append(h)
            cs.append(torch.stack(c).to(h.dtype))
            x = h
        H = torch.cat([zeros, torch.stack(hs, dim=1)])
        C = torch.cat([zeros, torch.stack(cs, dim=1)])
        return H, C

    def source_states_reference(self, x_src: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`source_states` one LSTM cell step at a time (the plain reference). Same shapes."""
        zeros = x_src.new_zeros(1, HIDDEN)
        state = [(zeros, zeros), (zeros, zeros)]
        hs, cs = [torch.cat([zeros, zeros])], [torch.cat([zeros, zeros])]
        for k in range(x_src.shape[0]):
            _, state = self._step(x_src[k : k + 1], state)
            hs.append(torch.cat([state[0][0], state[1][0]]))
            cs.append(torch.cat([state[0][1], state[1][1]]))
        return torch.stack(hs), torch.stack(cs)

    def contexts(
        self,
        feats: torch.Tensor,
        src_vec: torch.Tensor,
        src_pos: torch.Tensor,
        q_vec: torch.Tensor,
        q_pos: torch.Tensor,
        n_before: torch.Tensor,
    ) -> torch.Tensor:
        """LSTM outputs at the query steps.

        The LSTM is causal, so a query step's output depends only on the steps before it: the first
        ``n_before[b]`` sources (those at positions <= the query's; for a leave-one-out target t, the
        sources before t). Their states are computed once and shared by all queries, which equals running
        the LSTM over each query's full sequence (:func:`sequence_layout`; tested).

        feats: (S, 512) source features; src_vec: (S, 7); src_pos: (S,) ascending positions;
        q_vec: (B, 7); q_pos: (B,); n_before: (B,) int64 in [0, S]. -> (B, 512).
        """
        s = feats.shape[0]
        upto = min(int(n_before.max()) if len(n_before) else 0, s)
        x_src = self.step_input(feats[:upto], src_vec[:upto], src_pos[:upto])
        H, C = self.source_states(x_src)
        H, C = H[n_before], C[n_before]  # (B, 2, 512)
        b = q_vec.shape[0]
        x_q = self.step_input(self.query_feature.expand(b, -1), q_vec, q_pos)
        h, _ = self._step(x_q, [(H[:, 0], C[:, 0]), (H[:, 1], C[:, 1])])
        return h if self.context else torch.zeros_like(h)

    def contexts_reference(
        self,
        feats: torch.Tensor,
        src_vec: torch.Tensor,
        src_pos: torch.Tensor,
        q_vec: torch.Tensor,
        q_pos: torch.Tensor,
        layout: torch.Tensor,
    ) -> torch.Tensor:
        """:meth:`contexts` computed the slow, literal way: nn.LSTM over each query's whole sequence
        (layout (B, L) from :func:`sequence_layout`). For tests."""
        b, L = layout.shape
        is_q = layout < 0
        ids = layout.clamp(min=0)
        f = torch.where(is_q[..., None], self.query_feature.expand(b, L, -1), feats[ids])
        vec = torch.where(is_q[..., None], q_vec[:, None, :].expand(b, L, 7), src_vec[ids])
        pos = torch.where(is_q, q_pos[:, None].expand(b, L), src_pos[ids])
        out, _ = self.lstm(self.step_input(f, vec, pos))
        h = out[is_q]
        return h if self.context else torch.zeros_like(h)
