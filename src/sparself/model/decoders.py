"""Decoders: from the LSTM output at a query step to an image.

- ``fc`` (the paper's): one linear layer 512 -> h*w*3 at a low resolution, upsampled to the target size.
  It can only reproduce what it memorised; kept as the faithful reproduction.
- ``sweep`` (default): a small 3D CNN over a plane-sweep volume of the two bracketing source views
  warped into the target camera. It predicts a softmax over depth planes and a per-plane blend weight
  between the two sources, plus a small residual; the LSTM output modulates its features (FiLM).
  A learned per-pixel gate mixes that depth-resolved colour with a fallback: the distance-weighted blend
  of the two sources aligned to the target by optical flow (``fallback="flow"``, the default of
  :class:`sparself.synthesis.train.TrainConfig`) or as they are (``"blend"``), so that where no depth is
  photo-consistent (wide-baseline rings, dark backgrounds) the decoder can do what flow interpolation
  does. It is fully convolutional, so it trains on crops and runs at any resolution.
  With more than two sources per query (``TrainConfig.sources``), the matching cost is the mean over
  source pairs and the colour a per-voxel softmax over the visible sources, weighted by a small head on
  the context-conditioned (FiLM) features and each source's deviation from the others (the pair keeps
  its learned blend weight; further sources start down-weighted). Every decoder also returns a
  per-pixel confidence (:meth:`SweepDecoder.with_confidence`, :func:`confidence_map`).

Measured quality, against the classical baselines on held-out real frames: the README's Results
(benchmarks/synthesis_quality.py, benchmarks/table3.py).

Every decoder is called as ``decoder(sources, queries, ctx) -> (T, 3, h, w)`` (see
:mod:`sparself.model.query`): ``ctx`` (T, 512) is the LSTM output at each query step. ``reads_sources``
says whether it reads the source images of each query's source set (then it is fully convolutional,
trains on crops and can use flow-aligned sources); ``native_hw(hw)`` is the size it renders an image of
size hw at before any resizing (training compares at that size).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import torch
import torch.nn as nn
import torch.nn.functional as F
from kornia.metrics import ssim as kornia_ssim

from sparself.core.warp import homography_warp, plane_sweep
from sparself.model.cnn_lstm import Decoder

if TYPE_CHECKING:
    from sparself.model.query import Crop, Queries, Sources


class FCDecoder(Decoder):
    """The paper's output layer: Output = W_out h + b_out reshaped to (3, h, w), resized to the queries'
    size. It reads only the context, never the sources."""

    reads_sources = False

    def __init__(self, out_hw: tuple[int, int], hidden: int = 512) -> None:
        super().__init__()
        self.out_hw = (int(out_hw[0]), int(out_hw[1]))
        self.fc = nn.Linear(hidden, 3 * self.out_hw[0] * self.out_hw[1])
        nn.init.zeros_(self.fc.weight)
        nn.init.constant_(self.fc.bias, 0.5)  # start from mid-grey, not noise

    def native_hw(self, hw: tuple[int, int]) -> tuple[int, int]:
        return self.out_hw

    def decode_context(self, ctx: torch.Tensor) -> torch.Tensor:
        """ctx (B, 512) -> (B, 3, h, w) on the decoder's own grid."""
        return self.fc(ctx).view(-1, 3, *self.out_hw)

    def forward(self, sources: "Sources", queries: "Queries", ctx: torch.Tensor) -> torch.Tensor:
        out = self.decode_context(ctx)
        if tuple(queries.hw) != self.out_hw:
            out = F.interpolate(out, size=tuple(queries.hw), mode="bilinear", align_corners=False)
        return out

    def with_confidence(self, sources: "Sources", queries: "Queries", ctx: torch.Tensor):
        """:meth:`forward` and a confidence of 1 everywhere (this decoder has no measure of its own)."""
        out = self.forward(sources, queries, ctx)
        return out, torch.ones_like(out[:, :1])


def blend_weights(w2c_src: torch.Tensor, w2c_dst: torch.Tensor) -> torch.Tensor:
    """Plain-blend weights of two sources for a target: inverse to their camera-centre distances,
    ``w_1 = d_2 / (d_1 + d_2)``, ``w_2 = d_1 / (d_1 + d_2)`` (the index-weighted blend for a target
    between them; equal weights if both distances vanish). w2c_src (2, 4, 4); w2c_dst (4, 4) -> (2,)."""

    def centre(m):
        return -(m[..., :3, :3].transpose(-1, -2) @ m[..., :3, 3:4])[..., 0]

    d = (centre(w2c_src) - centre(w2c_dst)).norm(dim=-1)
    tot = d.sum()
    if float(tot) <= 1e-12:
        return torch.full_like(d, 0.5)
    return d.flip(0) / tot


def sweep_volume(
    src: torch.Tensor,
    K_src: torch.Tensor,
    w2c_src: torch.Tensor,
    K_dst: torch.Tensor,
    w2c_dst: torch.Tensor,
    depths: torch.Tensor,
    out_hw: tuple[int, int],
    plain: torch.Tensor | None = None,
) -> torch.Tensor:
    """Decoder input for one target: its n >= 2 sources (the bracketing pair first) warped onto every
    depth plane, plus one plane of the sources unwarped (the plain blend's input), or the pair aligned by
    optical flow when ``plain`` is given.

    src: (n, 3, H, W); K_src (n, 3, 3); w2c_src (n, 4, 4); K_dst (3, 3) (shifted for a crop);
    w2c_dst (4, 4); depths (D,). -> (4n, D + 1, h, w): channels 0..3n-1 the sources' colours, 3n..4n-1
    their validity (for n = 2: colours of both (6), validity (2)). Planes 0..D-1: the depth planes. Plane
    D: the sources mapped by their intrinsics only (``K_src K_dst^-1``: the source image resized/cropped
    to the target camera, as the plain-blend baseline uses it), with validity times the pair's
    :func:`blend_weights` (0 for further sources). plain: (2, 3, h, w), the pair already aligned to the
    target (e.g. by flow, :func:`sparself.core.warp.flow_pair`), used for plane D instead (validity 1).
    """
    n = src.shape[0]
    vol, valid = plane_sweep(src, K_src, w2c_src, K_dst, w2c_dst, depths, out_hw)  # (n,D,3,h,w), (n,D,1,h,w)
    K_src_t = torch.as_tensor(K_src, dtype=src.dtype, device=src.device)
    K_dst_t = torch.as_tensor(K_dst, dtype=src.dtype, device=src.device)
    if plain is None or n > 2:
        ident, ivalid = homography_warp(src, K_src_t @ torch.linalg.inv(K_dst_t)[None], out_hw)  # (n,3,h,w)
    if plain is not None:
        ident = torch.cat([plain.to(src.dtype), ident[2:]]) if n > 2 else plain.to(src.dtype)
        ivalid = torch.cat([torch.ones_like(plain[:, :1], dtype=src.dtype), *([ivalid[2:]] if n > 2 else [])])
    wts = blend_weights(
        torch.as_tensor(w2c_src[:2], dtype=torch.float64, device=src.device),
        torch.as_tensor(w2c_dst, dtype=torch.float64, device=src.device),
    ).to(src.dtype)
    wts = torch.cat([wts, wts.new_zeros(n - 2)])
    vol = torch.cat([vol * valid, (ident * ivalid)[:, None]], dim=1)  # (n, D+1, 3, h, w)
    valid = torch.cat([valid, (ivalid * wts[:, None, None, None])[:, None]], dim=1)
    x = torch.cat([*vol, *valid], dim=1)  # (D+1, 4n, h, w)
    return x.permute(1, 0, 2, 3).contiguous()


class SweepDecoder(Decoder):
    """Small 3D CNN over a plane-sweep volume, FiLM-conditioned on the LSTM output.

    Input x: (B, 8, D + 1, h, w) from :func:`sweep_volume`; ctx: (B, 512). Output (B, 3, h, w):
    sum_d p_d (a_d c1_d + (1 - a_d) c2_d) over valid samples (p = softmax over the D planes, a = blend
    weight per plane), plus a small 2D residual. Per voxel the CNN sees the photo-consistency of the two
    sources (their colour difference, raw and box-filtered over each of ``windows`` px, as in plane-sweep
    stereo) and their validity; the box filter gives a wide matching window for little compute (2 CPU
    cores). The depth logits add a plane-sweep prior, -cost_scale x the box-filtered cost, so the untrained
    decoder is already a soft winner-take-all sweep and training learns corrections (which matters when
    a capture has few frames to learn from).

    gate: mix the depth-resolved colour with the blend of the last plane of x (the two sources unwarped,
    or aligned by optical flow) through a learned per-pixel gate g (output = g sweep + (1 - g) blend, then
    the residual). Where the sweep finds no consistent depth (wide baselines, textureless or dark
    surroundings) the decoder can fall back to that blend. The gate's logit starts at ``gate_init`` (negative: towards
    the blend) and is scaled by ``gate_gain`` so that it can move a few units within a short training.

    Whole images are decoded several at a time (at most ``max_voxels`` of sweep volume per call) when
    their long side is at most ``tile`` px, else one at a time in overlapping tiles of ``tile`` px
    (bounded memory); both equal decoding each image at once (tested).
    """

    reads_sources = True
    tile = 256  # px
    tile_margin = 8  # px of context around each tile
    max_voxels = 2**25

    def __init__(
        self,
        channels: int = 8,
        hidden: int = 512,
        residual: bool = True,
        windows=(5,),
        extra_layers: int = 0,
        cost_scale: float = 30.0,
        gate: bool = True,
        gate_init: float = 0.0,
        gate_gain: float = 10.0,
        n_sources: int = 2,
    ) -> None:
        super().__init__()
        c = channels
        self.windows = tuple(int(k) for k in windows)
        self.conv_in = nn.Conv3d(3 + len(self.windows), c, 3, padding=1)
        self.extra = nn.ModuleList(nn.Conv3d(c, c, 3, padding=1) for _ in range(int(extra_layers)))
        self.conv_out = nn.Conv3d(c, 2, 3, padding=1)
        # depth prior: logits start as -cost_scale * (box-filtered matching cost), i.e. the network starts as a
        # soft winner-take-all plane sweep and learns corrections (converges with few training frames)
        self.cost_scale = nn.Parameter(torch.tensor(float(cost_scale)))
        self.film = nn.Linear(hidden, 2 * c)
        nn.init.zeros_(self.film.weight)  # FiLM starts as the identity
        nn.init.zeros_(self.film.bias)
        self.residual = (
            nn.Sequential(nn.Conv2d(3 + 3 + 1, 16, 3, padding=1), nn.ReLU(inplace=True), nn.Conv2d(16, 3, 3, padding=1))
            if residual
            else None
        )
        if self.residual is not None:
            _init_last(self.residual, 0.0)
        self.attend = None
        if n_sources > 2:  # per-source attention: context features, deviation, visibility, is-bracketing
            self.attend = nn.Sequential(nn.Conv3d(c + 3, c, 1), nn.ReLU(inplace=True), nn.Conv3d(c, 1, 1))
            _init_last(self.attend, 0.0)
            self.extra_bias = nn.Parameter(torch.tensor(-4.0))  # start close to the pair alone
        self.gate_gain = float(gate_gain)
        self.gate = None
        if gate:
            # inputs: sweep colour, blend colour, expected matching cost, sweep spread, cover, blend disagreement
            self.gate = nn.Sequential(
                nn.Conv2d(3 + 3 + 4, 16, 3, padding=1), nn.ReLU(inplace=True), nn.Conv2d(16, 1, 3, padding=1)
            )
            _init_last(self.gate, float(gate_init) / self.gate_gain)

    def native_hw(self, hw: tuple[int, int]) -> tuple[int, int]:
        return hw[0], hw[1]

    def forward(self, sources: "Sources", queries: "Queries", ctx: torch.Tensor) -> torch.Tensor:
        """Each query (or its crop) decoded from the sweep volume of its source set. -> (T, 3, h, w)."""
        return self.with_confidence(sources, queries, ctx)[0]

    def with_confidence(self, sources: "Sources", queries: "Queries", ctx: torch.Tensor):
        """:meth:`forward` and each pixel's confidence in [0, 1] (:meth:`decode_parts`).
        -> ((T, 3, h, w), (T, 1, h, w))."""
        if queries.crops is not None:
            x = torch.stack([_volume(sources, queries, b, c) for b, c in enumerate(queries.crops)])
            both = self._decode4(x, ctx)
        else:
            h, w = queries.hw
            if max(h, w) > self.tile:
                both = torch.stack([self._decode_tiled(sources, queries, ctx, b) for b in range(len(queries))])
            else:
                per = max(1, self.max_voxels // (len(sources.sweep_depths()) * h * w))
                both = torch.cat(
                    [
                        self._decode4(
                            torch.stack(
                                [
                                    _volume(sources, queries, b, (0, 0, h, w))
                                    for b in range(a, min(a + per, len(queries)))
                                ]
                            ),
                            ctx[a : a + per],
                        )
                        for a in range(0, len(queries), per)
                    ]
                )
        return both[:, :3], both[:, 3:]

    def _decode4(self, x: torch.Tensor, ctx: torch.Tensor) -> torch.Tensor:
        parts = self.decode_parts(x, ctx)
        return torch.cat([parts.colour, parts.confidence], 1)

    def _decode_tiled(self, sources: "Sources", queries: "Queries", ctx: torch.Tensor, b: int) -> torch.Tensor:
        """Query b's whole image (colour and confidence) in overlapping tiles. -> (4, H, W)."""
        (h, w), tile, margin = queries.hw, self.tile, self.tile_margin
        out = torch.zeros(4, h, w, device=ctx.device)
        for y0 in range(0, h, tile):
            for x0 in range(0, w, tile):
                ya, xa = max(0, y0 - margin), max(0, x0 - margin)
                yb, xb = min(h, y0 + tile + margin), min(w, x0 + tile + margin)
                x = _volume(sources, queries, b, (ya, xa, yb - ya, xb - xa))
                pred = self._decode4(x[None], ctx[b][None])[0]
                th, tw = min(tile, h - y0), min(tile, w - x0)
                out[:, y0 : y0 + th, x0 : x0 + tw] = pred[:, y0 - ya : y0 - ya + th, x0 - xa : x0 - xa + tw]
        return out

    def decode_volume(self, x: torch.Tensor, ctx: torch.Tensor, return_gate: bool = False):
        """x: (B, 4n, D + 1, h, w) from :func:`sweep_volume`; ctx: (B, 512) -> (B, 3, h, w) (and the gate
        (B, 1, h, w) if asked; ones without a gate)."""
        parts = self.decode_parts(x, ctx)
        return (parts.colour, parts.gate) if return_gate else parts.colour

    def _depth_and_colour(self, c, v, ctx):
        """Per-voxel depth probabilities and source-weighted colour. c (B, n, 3, D, h, w), v (B, n, 1, D, h, w)
        -> p (B, 1, D, h, w), colour (B, 3, D, h, w), cost (B, D, h, w)."""
        diff = match_cost(c[:, :2], v[:, :2])  # the pair's (all pairs measured worse: see the README)
        b, _, d, h, w = diff.shape
        flat = diff.permute(0, 2, 1, 3, 4).reshape(b * d, 1, h, w)
        boxes = [
            F.avg_pool2d(flat, k, 1, k // 2, count_include_pad=False).reshape(b, d, 1, h, w).permute(0, 2, 1, 3, 4)
            for k in self.windows
        ]
        v1, v2 = v[:, 0], v[:, 1]
        feat = torch.cat([diff, *boxes, v1, v2], 1).contiguous(memory_format=torch.channels_last_3d)
        hid = self.conv_in(feat)
        g, beta = self.film(ctx).chunk(2, dim=1)
        hid = F.relu(hid * (1 + g[:, :, None, None, None]) + beta[:, :, None, None, None])
        for conv in self.extra:
            hid = F.relu(conv(hid))
        logits = self.conv_out(hid)  # (B, 2, D, h, w)
        cost = torch.stack(boxes).mean(0)[:, 0]  # (B, D, h, w)
        p = torch.softmax(logits[:, 0] - self.cost_scale * cost, dim=1)[:, None]  # over depth
        if self.attend is None:  # the bracketing pair: one blend weight per voxel
            a = torch.sigmoid(logits[:, 1])[:, None]
            w1, w2 = a * v1, (1 - a) * v2
            return p, (w1 * c[:, 0] + w2 * c[:, 1]) / (w1 + w2).clamp(min=1e-6), cost
        return p, self._attended_colour(c, v, hid, logits[:, 1]), cost

    def _attended_colour(self, c, v, hid, pair_logit):
        """Colour from n > 2 sources: per-voxel softmax weights over the visible sources, from the
        context-conditioned features ``hid`` and each source's deviation from the visible mean colour.
        The pair keeps its learned blend logit; further sources start strongly down-weighted."""
        n = c.shape[1]
        mean = (v * c).sum(1, keepdim=True) / v.sum(1, keepdim=True).clamp(min=1e-6)
        dev = (c - mean).abs().mean(2, keepdim=True) * v  # (B, n, 1, D, h, w)
        flag = torch.zeros_like(dev)
        flag[:, :2] = 1
        per = torch.cat([hid[:, None].expand(-1, n, -1, -1, -1, -1), dev, v, flag], 2)
        logit = self.attend(per.flatten(0, 1)).view(v.shape)  # (B, n, 1, D, h, w)
        pair = torch.cat([pair_logit[:, None, None], torch.zeros_like(logit[:, 1:])], 1)
        logit = logit + self.extra_bias * (1 - flag) + pair
        logit = logit.masked_fill(v <= 0, -1e4)
        wts = torch.softmax(logit, 1) * v
        return (wts * c).sum(1) / wts.sum(1).clamp(min=1e-6)

    def decode_parts(self, x: torch.Tensor, ctx: torch.Tensor) -> "Decoded":
        """Colour, gate and confidence of a batch of volumes. x: (B, 4n, D + 1, h, w); ctx: (B, 512)."""
        b, ch, d1, h, w = x.shape
        n = ch // 4
        c = x[:, : 3 * n].reshape(b, n, 3, d1, h, w)
        v = x[:, 3 * n :].reshape(b, n, 1, d1, h, w)
        p, colour, cost = self._depth_and_colour(c[..., :-1, :, :], v[..., :-1, :, :], ctx)
        out = (p * colour).sum(2)  # (B, 3, h, w)
        cover = (p * (v[..., :-1, :, :].sum(1) > 0).to(x.dtype)).sum(2)  # how much of p saw a source
        spread = (p * (colour - out[:, :, None]).abs()).sum(2)  # disagreement along depth
        p1, p2, pw1, pw2 = c[:, 0, :, -1], c[:, 1, :, -1], v[:, 0, :, -1], v[:, 1, :, -1]
        plain_diff = (p1 - p2).abs().mean(1, keepdim=True)
        exp_cost = (p[:, 0] * cost).sum(1, keepdim=True)
        gate = torch.ones_like(cover)
        if self.gate is not None:
            blend = (pw1 * p1 + pw2 * p2) / (pw1 + pw2).clamp(min=1e-6)
            gin = torch.cat([out, blend, exp_cost, spread.mean(1, keepdim=True), cover, plain_diff], 1)
            gate = torch.sigmoid(self.gate_gain * self.gate(gin))
            out = gate * out + (1 - gate) * blend
        if self.residual is not None:
            out = out + self.residual(torch.cat([out, spread, cover], 1))
        return Decoded(out, gate, confidence_map(p, exp_cost, spread.mean(1, keepdim=True), plain_diff, gate))


@dataclass
class Decoded:
    """What the sweep decoder computes for a batch: colour (B, 3, h, w), gate (B, 1, h, w) (the weight of
    the depth-resolved colour against the fallback) and confidence (B, 1, h, w) in [0, 1]."""

    colour: torch.Tensor
    gate: torch.Tensor
    confidence: torch.Tensor


AGREEMENT_SCALE = 0.1  # a mean absolute colour difference (0..1) at which agreement falls to 1/e


def confidence_map(
    p: torch.Tensor, exp_cost: torch.Tensor, spread: torch.Tensor, plain_diff: torch.Tensor, gate: torch.Tensor
) -> torch.Tensor:
    """Per-pixel confidence in [0, 1]. Where the depth-resolved colour is used (gate g): the depth's
    certainty times the sources' agreement at that depth, exp(-expected matching cost / AGREEMENT_SCALE);
    the certainty is the peakedness of the depth distribution (1 - entropy / log D), raised towards 1
    where the plausible depths give the same colour anyway (small ``spread``). Where the fallback is used
    (1 - g): the pair's agreement after alignment. p (B, 1, D, h, w); the others (B, 1, h, w)."""
    d = p.shape[2]
    entropy = -(p * p.clamp(min=1e-12).log()).sum(2)
    peak = (1 - entropy / math.log(d)).clamp(0, 1) if d > 1 else torch.ones_like(entropy)
    certain = peak + (1 - peak) * torch.exp(-spread / AGREEMENT_SCALE)
    sweep = certain * torch.exp(-exp_cost / AGREEMENT_SCALE)
    fallback = torch.exp(-plain_diff / AGREEMENT_SCALE)
    return (gate * sweep + (1 - gate) * fallback).clamp(0, 1)


def _init_last(seq: nn.Sequential, bias: float) -> None:
    """Zero the weights of ``seq``'s last convolution and set its bias: the branch starts as a constant."""
    last = seq[-1]
    assert isinstance(last, (nn.Conv2d, nn.Conv3d)) and last.bias is not None
    nn.init.zeros_(last.weight)
    nn.init.constant_(last.bias, bias)


def match_cost(c: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Photo-consistency per voxel: the mean over source pairs of their mean absolute colour difference
    where both see the voxel, 1 (mismatch) where one does not. c (B, n, 3, D, h, w); v (B, n, 1, D, h, w)
    -> (B, 1, D, h, w)."""
    n = c.shape[1]
    total: torch.Tensor | int = 0
    for i in range(n):
        for j in range(i + 1, n):
            both = v[:, i] * v[:, j]
            total = total + (c[:, i] - c[:, j]).abs().mean(1, keepdim=True) * both + (1 - both)
    assert isinstance(total, torch.Tensor)  # at least two sources
    return total / (n * (n - 1) // 2)


DecoderName = Literal["sweep", "fc"]  # the keys of DECODERS
# name -> class (each has ``reads_sources``)
DECODERS: dict[str, type[Decoder]] = {"sweep": SweepDecoder, "fc": FCDecoder}


def _volume(sources: "Sources", queries: "Queries", b: int, crop: "Crop") -> torch.Tensor:
    """:func:`sweep_volume` of query b's source set for its crop (y0, x0, h, w). -> (8, D + 1, h, w)."""
    y0, x0, h, w = crop
    s = list(queries.sets[b])
    plain = None if queries.aligned is None else queries.aligned[b][:, :, y0 : y0 + h, x0 : x0 + w]
    return sweep_volume(
        sources.images[s],
        sources.K[s],
        sources.w2c[s],
        queries.crop_camera(b, crop),
        queries.w2c[b],
        sources.sweep_depths(),
        (h, w),
        plain,
    )


def build_decoder(
    name: str,
    channels: int = 8,
    fc_hw: tuple[int, int] = (32, 32),
    windows=(5,),
    extra_layers: int = 0,
    gate: bool = True,
    gate_init: float = 0.0,
    n_sources: int = 2,
) -> Decoder:
    if name == "sweep":
        return SweepDecoder(
            channels, windows=windows, extra_layers=extra_layers, gate=gate, gate_init=gate_init, n_sources=n_sources
        )
    if name == "fc":
        return FCDecoder(fc_hw)
    raise ValueError(f"unknown decoder {name!r}; choose one of {', '.join(DECODERS)}")


def synthesis_loss(pred: torch.Tensor, gt: torch.Tensor, ssim_weight: float = 0.0, window: int = 7) -> torch.Tensor:
    """Training loss: MSE + ``ssim_weight`` x (1 - SSIM) (Gaussian window of ``window`` px, kornia).
    pred, gt: (B, 3, h, w) in [0, 1], computed in float32. -> scalar."""
    pred, gt = pred.float(), gt.float()
    loss = F.mse_loss(pred, gt)
    if ssim_weight > 0:
        loss = loss + ssim_weight * (1 - kornia_ssim(pred, gt, window).mean())
    return loss
