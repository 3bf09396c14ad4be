"""The CNN–LSTM network: backbone layout and weight loading, encodings, causal contexts, decoders."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
import torch

from sparself.core.errors import ConfigError, InputError
from sparself.core.geometry import Pose, rotmat_to_quat
from sparself.model import (
    CNNLSTM,
    FCDecoder,
    PoseNorm,
    ResNet18,
    SweepDecoder,
    load_resnet18_weights,
    positional_encoding,
    sequence_layout,
)
from sparself.model import backbone as bb_mod

torch.set_num_threads(1)  # shared cores: 1 thread is faster there


def test_backbone_keys_follow_torchvision_layout_and_pool_to_512():
    m = ResNet18()
    keys = list(m.state_dict())
    # torchvision's resnet18().state_dict() has 122 entries; without fc.weight / fc.bias: 120
    assert len(keys) == 120
    for k in [
        "conv1.weight",
        "bn1.running_mean",
        "bn1.num_batches_tracked",
        "layer1.0.conv1.weight",
        "layer1.1.bn2.bias",
        "layer2.0.downsample.0.weight",
        "layer2.0.downsample.1.running_var",
        "layer4.1.conv2.weight",
        "layer4.1.bn2.weight",
    ]:
        assert k in keys
    assert not any(k.startswith("fc.") for k in keys)
    assert "layer1.0.downsample.0.weight" not in keys  # no projection where shapes already match
    assert m.layer4[1].conv2.weight.shape == (512, 512, 3, 3)
    out = m.eval()(torch.rand(2, 3, 64, 64))
    assert out.shape == (2, 512)


def test_backbone_batchnorm_is_frozen_so_frames_do_not_mix():
    m = ResNet18().train()
    x = torch.rand(3, 3, 32, 32)
    a = m(x)
    b = m(torch.cat([x[:1], torch.rand(2, 3, 32, 32)]))
    assert torch.allclose(a[0], b[0], atol=1e-6)  # frame 0's features ignore the rest of the batch


def _torchvision_style_checkpoint(path, seed=0):
    g = torch.Generator().manual_seed(seed)
    sd = {
        k: (torch.rand(v.shape, generator=g) if v.is_floating_point() else v.clone())
        for k, v in ResNet18().state_dict().items()
    }
    sd["fc.weight"] = torch.rand(1000, 512, generator=g)  # torchvision's file still has the classifier
    sd["fc.bias"] = torch.rand(1000, generator=g)
    torch.save(sd, path)
    return sd


def test_weights_load_strictly_from_a_torchvision_layout_file(tmp_path):
    sd = _torchvision_style_checkpoint(tmp_path / "resnet18.pth")
    m = ResNet18()
    assert load_resnet18_weights(m, tmp_path / "resnet18.pth") == str(tmp_path / "resnet18.pth")
    for k, v in m.state_dict().items():
        assert torch.equal(v, sd[k]), k


def test_weights_from_hub_cache_else_one_note(tmp_path, monkeypatch, caplog):
    """Without cached weights the backbone starts random and says so once, at INFO (no warning on every run)."""
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    m = ResNet18()
    before = {k: v.clone() for k, v in m.state_dict().items()}
    with caplog.at_level(logging.INFO):
        assert load_resnet18_weights(m) == "random"
    notes = [r for r in caplog.records if bb_mod.RESNET18_URL in r.getMessage()]
    assert len(notes) == 1 and notes[0].levelno == logging.INFO
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert all(torch.equal(v, before[k]) for k, v in m.state_dict().items())
    cached = tmp_path / "hub" / "checkpoints" / "resnet18-f37072fd.pth"
    cached.parent.mkdir(parents=True)
    sd = _torchvision_style_checkpoint(cached, seed=1)
    assert load_resnet18_weights(m) == str(cached)
    assert torch.equal(m.conv1.weight, sd["conv1.weight"])


def test_wrong_weight_files_give_clear_errors(tmp_path):
    m = ResNet18()
    with pytest.raises(InputError, match="not found"):
        load_resnet18_weights(m, tmp_path / "missing.pth")
    (tmp_path / "text.pth").write_text("not a checkpoint")
    with pytest.raises(InputError, match="cannot read"):
        load_resnet18_weights(m, tmp_path / "text.pth")
    sd = {k: v for k, v in ResNet18().state_dict().items() if not k.startswith("layer4")}
    torch.save(sd, tmp_path / "partial.pth")
    with pytest.raises(ConfigError, match="missing keys"):
        load_resnet18_weights(m, tmp_path / "partial.pth")
    sd = ResNet18().state_dict()
    sd["conv1.weight"] = torch.zeros(64, 1, 7, 7)
    torch.save(sd, tmp_path / "shape.pth")
    with pytest.raises(ConfigError, match="shape mismatch"):
        load_resnet18_weights(m, tmp_path / "shape.pth")


def test_positional_encoding_matches_the_formula_at_fractional_positions():
    pe = positional_encoding(torch.tensor([0.0, 3.5]), 512)
    assert pe.shape == (2, 512)
    assert torch.allclose(pe[0, 0::2], torch.zeros(256)) and torch.allclose(pe[0, 1::2], torch.ones(256))
    i = 10  # dimension pair 2i, 2i+1
    ang = 3.5 / 10000 ** (2 * i / 512)
    assert math.isclose(pe[1, 2 * i].item(), math.sin(ang), abs_tol=1e-6)
    assert math.isclose(pe[1, 2 * i + 1].item(), math.cos(ang), abs_tol=1e-6)


def test_pose_vectors_ignore_world_origin_and_scale_and_quaternion_sign():
    rng = np.random.default_rng(0)
    poses = [Pose.from_center(rng.normal(size=4), rng.normal(size=3)) for _ in range(5)]
    centers = np.stack([p.center for p in poses])
    norm = PoseNorm(tuple(centers.mean(0)), 2.0)
    v = norm.vectors(poses)
    # the same capture in a world moved by (R0, t0) and scaled by s gives the same network inputs
    s, t0 = 3.0, np.array([1.0, -2.0, 5.0])
    R0 = Pose.from_center(np.array([0.9, 0.1, -0.3, 0.2]), np.zeros(3)).R
    moved = []
    for p in poses:
        R = p.R @ R0.T  # world' = s R0 world + t0
        moved.append(Pose.from_center(rotmat_to_quat(R), s * R0 @ p.center + t0))
    c2 = np.stack([p.center for p in moved])
    v2 = PoseNorm(tuple(c2.mean(0)), 2.0 * s).vectors(moved)
    assert np.allclose(v[:, :3], v2[:, :3], atol=1e-5)
    assert np.all(v[:, 3] >= 0)
    flipped = Pose(-poses[0].qvec, poses[0].tvec)
    assert np.allclose(norm.vector(flipped), v[0])
    assert np.allclose(
        np.linalg.norm(v[:, :3], axis=1), np.linalg.norm(centers - centers.mean(0), axis=1) / 2.0, atol=1e-5
    )


def _net(decoder=None, context=True):
    torch.manual_seed(0)
    return CNNLSTM(decoder or FCDecoder((4, 6)), backbone_size=32, context=context).eval()


def test_causal_contexts_equal_the_lstm_over_each_full_sequence():
    net = _net()
    s = 6
    feats, vec = torch.randn(s, 512), torch.randn(s, 7)
    src_pos = np.arange(s, dtype=np.float64)
    # leave-one-out queries (target t replaced by its query step) ...
    t = np.array([0, 2, 5])
    ref = net.contexts_reference(
        feats,
        vec,
        torch.tensor(src_pos).float(),
        vec[t],
        torch.tensor(t).float(),
        torch.from_numpy(sequence_layout(s, src_pos, src_pos[t], t)),
    )
    got = net.contexts(feats, vec, torch.tensor(src_pos).float(), vec[t], torch.tensor(t).float(), torch.as_tensor(t))
    assert torch.allclose(got, ref, atol=1e-5)
    # ... and novel queries at fractional positions among all sources, one sequence each
    q = np.array([-1.2, 0.5, 3.5, 6.2])
    qv = torch.randn(4, 7)
    ref = net.contexts_reference(
        feats,
        vec,
        torch.tensor(src_pos).float(),
        qv,
        torch.tensor(q).float(),
        torch.from_numpy(sequence_layout(s, src_pos, q, -np.ones(4, np.int64))),
    )
    got = net.contexts(
        feats,
        vec,
        torch.tensor(src_pos).float(),
        qv,
        torch.tensor(q).float(),
        torch.as_tensor(np.searchsorted(src_pos, q, side="right")),
    )
    assert torch.allclose(got, ref, atol=1e-5)


def test_sequence_layout_puts_the_query_in_index_order():
    with pytest.raises(ValueError, match="ragged"):
        sequence_layout(4, np.arange(4.0), np.array([2.0, 1.5]), np.array([2, -1]))
    lay = sequence_layout(4, np.arange(4.0), np.array([2.0]), np.array([2]))
    assert lay.tolist() == [[0, 1, -1, 3]]
    lay = sequence_layout(4, np.arange(4.0), np.array([1.5]), np.array([-1]))
    assert lay.tolist() == [[0, 1, -1, 2, 3]]


def test_no_context_ablation_zeroes_the_decoder_input():
    net = _net(context=False)
    h = net.contexts(
        torch.randn(3, 512),
        torch.randn(3, 7),
        torch.arange(3.0),
        torch.randn(2, 7),
        torch.tensor([0.5, 1.5]),
        torch.tensor([1, 2]),
    )
    assert h.shape == (2, 512) and torch.count_nonzero(h) == 0


def test_decoder_shapes_and_initial_sweep_output_is_a_blend_of_sources():
    fc = FCDecoder((5, 7))
    assert fc.decode_context(torch.randn(3, 512)).shape == (3, 3, 5, 7)
    dec = SweepDecoder(channels=4)
    x = torch.rand(2, 8, 6, 10, 12)
    x[:, 6:] = 1.0  # both sources valid everywhere
    out = dec.decode_volume(x, torch.randn(2, 512))
    assert out.shape == (2, 3, 10, 12)
    # untrained residual is zero, so each output pixel is a convex combination of source samples
    lo = torch.minimum(x[:, 0:3], x[:, 3:6]).amin(2)
    hi = torch.maximum(x[:, 0:3], x[:, 3:6]).amax(2)
    assert torch.all(out >= lo - 1e-5) and torch.all(out <= hi + 1e-5)
    # a full network: encode, contexts, decode
    net = _net(SweepDecoder(4))
    f = net.encode(net.backbone_input(torch.rand(3, 3, 20, 30)))
    assert f.shape == (3, 512)


def test_sweep_volume_last_plane_is_the_plain_blend_input():
    from sparself.model import sweep_volume
    from sparself.model.decoders import blend_weights

    K = torch.tensor([[20.0, 0, 16], [0, 20.0, 12], [0, 0, 1]])
    w2c = torch.eye(4).repeat(3, 1, 1)
    w2c[0, 0, 3], w2c[1, 0, 3], w2c[2, 0, 3] = 0.0, -3.0, -1.0  # centres x = 0, 3 and the target at 1
    src = torch.rand(2, 3, 24, 32)
    Kc = K.clone()
    Kc[0, 2] -= 4  # a crop starting at x = 4, y = 2
    Kc[1, 2] -= 2
    x = sweep_volume(src, K[None].repeat(2, 1, 1), w2c[:2], Kc, w2c[2], torch.tensor([2.0, 5.0]), (10, 12))
    assert x.shape == (8, 3, 10, 12)
    # same intrinsics: the unwarped plane is the crop of each source itself
    assert torch.allclose(x[0:3, -1], src[0, :, 2:12, 4:16], atol=1e-5)
    assert torch.allclose(x[3:6, -1], src[1, :, 2:12, 4:16], atol=1e-5)
    # plain-blend weights: the target is 1 from source 0 and 2 from source 1 -> 2/3, 1/3
    assert torch.allclose(blend_weights(w2c[:2].double(), w2c[2].double()), torch.tensor([2 / 3, 1 / 3]).double())
    assert torch.allclose(x[6, -1], torch.full((10, 12), 2 / 3)) and torch.allclose(
        x[7, -1], torch.full((10, 12), 1 / 3)
    )


def test_sweep_gate_interpolates_between_the_sweep_and_the_plain_blend():
    x = torch.rand(2, 8, 5, 9, 11)
    x[:, 6:, :-1] = 1.0
    x[:, 6, -1], x[:, 7, -1] = 0.25, 0.75
    plain = 0.25 * x[:, 0:3, -1] + 0.75 * x[:, 3:6, -1]
    ctx = torch.randn(2, 512)
    to_blend = SweepDecoder(4, gate_init=-40.0)
    out, gate = to_blend.decode_volume(x, ctx, return_gate=True)
    assert torch.all(gate < 1e-6) and torch.allclose(out, plain, atol=1e-5)
    no_gate = SweepDecoder(4, gate=False)
    sweep_only = no_gate.decode_volume(x, ctx)
    half = SweepDecoder(4, gate_init=0.0)
    half.load_state_dict(
        {**no_gate.state_dict(), **{k: v for k, v in half.state_dict().items() if k.startswith("gate")}}
    )
    assert torch.allclose(half.decode_volume(x, ctx), 0.5 * sweep_only + 0.5 * plain, atol=1e-5)


def test_synthesis_loss_is_mse_plus_weighted_ssim_dissimilarity():
    from sparself.model.decoders import synthesis_loss

    gt = torch.rand(2, 3, 16, 16)
    pred = gt + 0.1 * torch.randn_like(gt)
    mse = torch.mean((pred - gt) ** 2)
    assert torch.allclose(synthesis_loss(pred, gt), mse)
    assert torch.allclose(synthesis_loss(gt, gt, 0.5), torch.tensor(0.0), atol=1e-5)  # SSIM(x, x) = 1
    with_ssim = synthesis_loss(pred, gt, 0.5)
    assert with_ssim > mse + 0.01  # noise lowers SSIM, so the term adds to the MSE


def test_weights_none_keeps_random_init_silently(tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    m = ResNet18()
    before = {k: v.clone() for k, v in m.state_dict().items()}
    with caplog.at_level(logging.WARNING):
        assert load_resnet18_weights(m, "none") == "random"
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert all(torch.equal(v, before[k]) for k, v in m.state_dict().items())


def test_fused_source_states_equal_the_step_by_step_lstm_values_and_gradients():
    """The fast path (fused LSTM + recomputed cell states) against the plain per-step cells."""
    net = _net().train()
    x = torch.randn(30, 1152, dtype=torch.float64, requires_grad=True)
    net = net.double()
    outs = []
    for fn in (net.source_states, net.source_states_reference):
        net.zero_grad()
        x.grad = None
        H, C = fn(x)
        w = torch.linspace(-1, 1, H.numel(), dtype=torch.float64).view_as(H)
        ((H * w).sum() + (C * w.flip(0)).sum()).backward()
        outs.append(
            (
                H.detach(),
                C.detach(),
                x.grad.clone(),
                net.lstm.weight_hh_l0.grad.clone(),
                net.lstm.weight_ih_l1.grad.clone(),
                net.lstm.bias_hh_l1.grad.clone(),
            )
        )
    assert outs[0][0].shape == (31, 2, 512)
    for a, b in zip(*outs):
        assert torch.allclose(a, b, atol=1e-9, rtol=1e-7)
    H, C = net.source_states(x[:0])
    assert H.shape == (1, 2, 512) and not H.any() and not C.any()


def test_queries_leave_one_out_novel_and_crops():
    """The query types training and synthesis share: a leave-one-out target never reads itself, novel
    queries sit after every source at or before them, a crop shifts the principal point by its corner."""
    from planescene import small_plane_scene
    from sparself.model.query import Sources, bracket, leave_one_out, novel_queries, render

    src = Sources.from_scene(small_plane_scene(5)).posed(PoseNorm((0.0, 0.0, 0.0), 1.0), np.array([2.0, 3.0]))
    loo = leave_one_out(src)
    assert all(t not in s and len(s) == 2 for t, s in enumerate(loo.sets))
    assert loo.sets[0] == (1, 2) and loo.sets[2] == (1, 3) and loo.n_before.tolist() == [0, 1, 2, 3, 4]
    sel = loo.select([3, 1])
    assert sel.sets == [loo.sets[3], loo.sets[1]] and torch.equal(sel.K[0], src.K[3])
    Kc = sel.crop_camera(0, (2, 5, 8, 8))
    assert torch.allclose(Kc[:2, 2], src.K[3][:2, 2] - torch.tensor([5.0, 2.0]))
    q = novel_queries(src, src.K[:2].numpy(), src.w2c[[1, 4]].numpy(), src.vectors[:2].numpy(), [1.5, 4.2], src.hw)
    assert q.n_before.tolist() == [2, 5] and q.sets == [bracket(src.positions, 1.5), (4, 3)]
    net = _net(FCDecoder((4, 6)))
    out = render(net, src, q)  # the fc decoder renders its grid, resized to the queries' size
    assert out.shape == (2, 3, *src.hw)


def test_k_nearest_source_sets_never_contain_the_target():
    """K sources per query: the bracketing pair first, then the others nearest by camera centre; a
    leave-one-out target never reads itself, for any K (and K larger than the sources available)."""
    from planescene import small_plane_scene
    from sparself.model.query import Sources, camera_centres, leave_one_out, novel_queries

    src = Sources.from_scene(small_plane_scene(7)).posed(PoseNorm((0.0, 0.0, 0.0), 1.0), np.array([2.0, 3.0]))
    centres = camera_centres(src.w2c)
    for k in (2, 3, 4, 10):
        loo = leave_one_out(src, k=k)
        for t, s in enumerate(loo.sets):
            assert t not in s and len(s) == min(k, len(src) - 1) and len(set(s)) == len(s)
            assert s[:2] == leave_one_out(src).sets[t]  # the pair comes first
            rest = [i for i in range(len(src)) if i not in (t, *s[:2])]
            d = np.linalg.norm(centres - centres[t], axis=1)
            assert sorted(d[list(s[2:])]) == sorted(d[rest])[: len(s) - 2]  # the nearest others
    q = novel_queries(src, src.K[:1].numpy(), src.w2c[3:4].numpy(), src.vectors[:1].numpy(), [2.5], src.hw, k=4)
    assert q.sets[0][:2] == (2, 3) and len(q.sets[0]) == 4 and 3 in q.sets[0]


def test_sweep_decoder_with_four_sources_runs_and_trains():
    """A decoder built for 4 sources reads 4-source volumes (the attention is learned: gradients reach it)
    and its outputs stay in range where all sources agree on a flat colour."""
    from sparself.model import sweep_volume

    dec = SweepDecoder(n_sources=4)
    src = torch.full((4, 3, 12, 14), 0.3)
    K = torch.tensor([[10.0, 0, 7], [0, 10.0, 6], [0, 0, 1]])
    w2c = torch.eye(4).repeat(4, 1, 1)
    w2c[:, 0, 3] = torch.tensor([-0.1, 0.1, -0.2, 0.2])
    x = sweep_volume(src, K.expand(4, 3, 3), w2c, K, torch.eye(4), torch.tensor([2.0, 4.0, 8.0]), (12, 14))
    assert x.shape == (16, 4, 12, 14)
    out = dec.decode_volume(x[None], torch.zeros(1, 512))
    assert torch.allclose(out[:, :, 3:-3, 3:-3], torch.full_like(out[:, :, 3:-3, 3:-3], 0.3), atol=1e-4)
    x2 = x.clone()
    x2[3:6, :, :, :7] = 0.9  # source 1 disagrees on the left half
    dec.decode_volume(x2[None], torch.randn(1, 512)).square().mean().backward()
    assert dec.attend[-1].weight.grad is not None and dec.attend[-1].weight.grad.abs().sum() > 0


def test_confidence_is_low_where_the_sources_disagree():
    """Two textured sources that agree at one depth plane on the right half (and after alignment) but at
    no depth on the left: the decoder's confidence is high on the right, low on the left, whatever the
    gate does."""
    from sparself.model.decoders import confidence_map

    h, w, d = 12, 20, 6
    gen = torch.Generator().manual_seed(0)
    c1 = torch.rand(1, 3, d + 1, h, w, generator=gen)
    c2 = torch.rand(1, 3, d + 1, h, w, generator=gen)
    c2[:, :, 2, :, w // 2 :] = c1[:, :, 2, :, w // 2 :]  # the right half's true depth: plane 2
    c2[:, :, d, :, w // 2 :] = c1[:, :, d, :, w // 2 :]  # and the aligned pair agrees there
    v = torch.ones(1, 1, d + 1, h, w)
    x = torch.cat([c1, c2, v, v], 1)
    for gate_init in (-5.0, 0.0, 5.0):
        dec = SweepDecoder(gate_init=gate_init)
        conf = dec.decode_parts(x, torch.zeros(1, 512)).confidence[0, 0]
        assert conf.shape == (h, w) and 0 <= conf.min() and conf.max() <= 1
        left, right = conf[:, 2 : w // 2 - 3].mean(), conf[:, w // 2 + 3 : -2].mean()
        assert right > 0.5 and left < 0.2 * right, (gate_init, left, right)
    # the parts: an ambiguous depth lowers confidence only where the candidate depths' colours differ
    flat = torch.full((1, 1, d, 2, 2), 1.0 / d)
    peaked = torch.zeros(1, 1, d, 2, 2)
    peaked[:, :, 2] = 1
    zero, one = torch.zeros(1, 1, 2, 2), torch.ones(1, 1, 2, 2)
    assert torch.allclose(confidence_map(flat, zero, one, zero, one), zero, atol=1e-4)
    assert torch.allclose(confidence_map(flat, zero, zero, zero, one), one, atol=1e-5)
    assert torch.allclose(confidence_map(peaked, zero, one, zero, one), one, atol=1e-5)
    assert torch.allclose(confidence_map(peaked, one, zero, zero, one), zero, atol=1e-4)  # sources disagree
    assert torch.allclose(confidence_map(flat, zero, one, zero, zero), one)  # the fallback's agreement


def test_closed_ring_pairs_the_last_source_with_the_first_instead_of_extrapolating():
    """On a ring (the last camera next to the first) a query beyond either end sits between the last
    source and the first, with t from the camera distances; on an open path (a line) it still
    extrapolates from the end pair, with t from the sequence positions."""
    from sparself.model.query import query_pair, source_set

    ang = np.radians(np.arange(8) * 45.0)  # 8 cameras around a full circle, in order
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(8)], 1)
    pos = np.arange(8, dtype=np.float64)
    q = np.array([np.cos(np.radians(330.0)), np.sin(np.radians(330.0)), 0.0])  # between camera 7 and 0
    pair, t = query_pair(pos, ring, 7.5, q)
    assert pair == (7, 0) and t == pytest.approx(1 / 3, abs=0.02)  # 15 deg from 7, 30 deg from 0
    assert query_pair(pos, ring, -0.5, q)[0] == (7, 0)  # the same pair from before the first
    assert source_set(pos, ring, 0.0, ring[0], exclude=0) == (7, 1)  # leave-one-out at the start
    assert source_set(pos, ring, 7.0, ring[7], exclude=7) == (6, 0)
    assert query_pair(pos, ring, 3.5, q) == ((3, 4), 0.5)  # within the sequence: unchanged
    line = np.stack([pos, np.zeros(8), np.zeros(8)], 1)
    assert query_pair(pos, line, 7.5, np.array([7.5, 0, 0])) == ((7, 6), -0.5)
    assert query_pair(pos, line, 0.0, line[0], exclude=0) == ((1, 2), -1.0)


def test_novel_and_leave_one_out_queries_carry_their_fractions_to_the_flow_alignment():
    """Queries keep each pair's t (selected with them); flow alignment at t = 0 / 1 returns the sources."""
    from planescene import small_plane_scene
    from sparself.model.query import Sources, flow_aligned, leave_one_out, novel_queries

    src = Sources.from_scene(small_plane_scene(5)).posed(PoseNorm((0.0, 0.0, 0.0), 1.0), np.array([2.0, 3.0]))
    loo = leave_one_out(src)
    assert loo.fractions.tolist() == [-1.0, 0.5, 0.5, 0.5, -1.0]  # an open line: the ends extrapolate
    assert loo.sets[4] == (3, 2) and loo.select([4, 1]).fractions.tolist() == [-1.0, 0.5]
    q = novel_queries(src, src.K[:2].numpy(), src.w2c[1:3].numpy(), src.vectors[:2].numpy(), [1.0, 1.5], src.hw)
    assert q.sets == [(1, 2), (1, 2)] and q.fractions.tolist() == [0.0, 0.5]
    a = flow_aligned(src, q.select([0])).aligned[0]
    assert torch.allclose(a[0], src.images[1], atol=1e-6)
