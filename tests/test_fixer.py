"""The fixer merges a synthesized view with a reconstruction's render where each is right, learns that only
from photos neither saw, and is used on a capture only when its merge beats both there."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from sparself.capture.io.dense import FixerCheck, SelfCheck, ViewCheck
from sparself.core import metrics
from sparself.evaluation.fixing import FixerPairs, beats, fixed, fixer_pairs, to_tensor, validated_fixer
from sparself.model.fixer import Fixer, best_gate, blend, fix_views, train_fixer


def _pairs(n: int = 4, h: int = 24, w: int = 32, seed: int = 0):
    """Truth images; views right on the left half, renders right on the right half, each wrong (noisy)
    elsewhere; the view's confidence is low where it is wrong."""
    g = torch.Generator().manual_seed(seed)
    truth = torch.rand(n, 3, h, w, generator=g)
    left = torch.zeros(1, 1, h, w)
    left[..., : w // 2] = 1.0
    noise = lambda: (truth + 0.3 * torch.randn(n, 3, h, w, generator=g)).clamp(0, 1)  # noqa: E731
    view = left * truth + (1 - left) * noise()
    render = (1 - left) * truth + left * noise()
    conf = (0.2 + 0.7 * left).expand(n, 1, h, w).clone()
    return view, render, conf, truth


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(np.mean([metrics.psnr(x.permute(1, 2, 0).numpy(), y.permute(1, 2, 0).numpy()) for x, y in zip(a, b)]))


def test_a_trained_fixer_takes_each_pixel_from_the_image_that_is_right_there_on_unseen_images():
    view, render, conf, truth = _pairs(seed=0)
    fixer = train_fixer(view, render, conf, truth, steps=300, seed=0)
    v2, r2, c2, t2 = _pairs(seed=1)  # other images, the same kind of errors
    with torch.no_grad():
        out = blend(fixer, v2, r2, c2)
    assert _psnr(out, t2) > max(_psnr(v2, t2), _psnr(r2, t2)) + 3.0


def test_the_best_gate_is_the_least_squares_blend_weighted_by_how_far_view_and_render_differ():
    view = torch.tensor([1.0, 1.0, 1.0, 0.5, 0.2, 0.6]).view(2, 3, 1, 1)
    render = torch.tensor([0.0, 0.0, 0.0, 0.5, 0.2, 0.6]).view(2, 3, 1, 1)  # the second agrees with its view
    truth = torch.tensor([0.1, 0.2, 0.45, 0.9, 0.9, 0.9]).view(2, 3, 1, 1)
    g, w = best_gate(view, render, truth)
    torch.testing.assert_close(g.flatten(), torch.tensor([0.25, 0.0]))  # (0.1 + 0.2 + 0.45) / 3
    torch.testing.assert_close(w.flatten(), torch.tensor([3.0, 0.0]))
    g, _ = best_gate(view, render, view * 2)  # past the view: the gate stops at 1
    assert float(g[0]) == 1.0


def test_a_gate_is_not_driven_to_the_image_that_is_right_more_often_everywhere():
    # photos of a textured plane: the view is badly wrong on the left half (and unsure there), the render a
    # little wrong on the right half; fitting the blend itself drove every gate to the render and left it
    # there, saturated. The fixer must take the view on the right.
    from planescene import plane_scene, render_plane

    scene = plane_scene(xs=(0.0, 0.1, 0.2))
    truth = to_tensor(np.stack([render_plane(f.pose, scene.cameras[f.camera_id]) for f in scene.frames]))
    w = truth.shape[-1]
    view, render = truth.clone(), truth.clone()
    view[..., : w // 2], render[..., w // 2 :] = 0.2, 0.5
    conf = torch.ones_like(truth[:, :1])
    conf[..., : w // 2] = 0.1
    fixer = train_fixer(view, render, conf, truth, steps=200, seed=0)
    with torch.no_grad():
        g = fixer(view, render, conf)
    assert float(g[..., : w // 2].mean()) < 0.05 and float(g[..., w // 2 :].mean()) > 0.95


def test_the_merge_must_beat_both_by_more_than_chance_over_the_photos():
    view, render = np.array([20.0, 21.0, 22.0]), np.array([19.0, 19.0, 19.0])
    assert beats(view + 1.0, view, render)  # +1 dB on every photo
    assert not beats(view + 0.01, view, render)  # under the 0.05 dB floor
    # +0.6 dB on average, but from one photo: the standard error (1.0 dB) is larger than the gain
    assert not beats(view + np.array([2.6, -0.6, -0.2]), view, render)
    assert beats(render + 0.5, render - 1.0, render)  # the render is the better of the two: gains count over it
    assert not beats(view[:1] + 5.0, view[:1], render[:1])  # one photo cannot show a spread


def test_a_merge_as_exact_as_exact_views_gains_nothing_and_computes_no_nan():
    exact = np.full(3, np.inf)  # PSNR of an image equal to its photo
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # inf - inf would warn, and its NaN decide by accident
        assert not beats(exact, exact, np.array([19.0, 19.0, 19.0]))
        assert not beats(np.array([np.inf, 20.0, 21.0]), np.array([np.inf, 20.0, 21.0]), np.full(3, 19.0))


def test_fixing_at_the_renders_size_is_the_blend_and_a_larger_view_is_corrected_in_its_low_frequencies():
    g = torch.Generator().manual_seed(0)
    smooth = lambda: F.interpolate(torch.rand(2, 3, 6, 8, generator=g), size=(24, 32), mode="bilinear")  # noqa: E731
    view, render, conf = smooth(), smooth(), smooth()[:, :1]
    fixer = Fixer()
    with torch.no_grad():
        torch.testing.assert_close(fix_views(fixer, view, render, conf), blend(fixer, view, render, conf).clamp(0, 1))
        big = F.interpolate(view, scale_factor=2, mode="nearest")
        out = fix_views(fixer, big, render, F.interpolate(conf, scale_factor=2, mode="nearest"))
    assert out.shape == big.shape
    # area-averaged back to the render's size it is the blend there (the correction is low-frequency only)
    small = F.interpolate(out, size=render.shape[-2:], mode="area")
    expect = blend(fixer, view, render, conf).detach()
    assert float((small - expect).abs().mean()) < 0.02


def test_the_same_seed_gives_the_same_fixer():
    view, render, conf, truth = _pairs()
    a, b = (train_fixer(view, render, conf, truth, steps=20, seed=3) for _ in range(2))
    for p, q in zip(a.parameters(), b.parameters()):
        assert torch.equal(p, q)


class _Render:
    """A renderer that returns fixed images per pose centre x (a fake fit)."""

    def __init__(self, scene, wrong_right: bool):
        self.scene, self.wrong_right = scene, wrong_right

    def render(self, pose, cam):
        from planescene import render_plane

        img = render_plane(pose, cam)
        if self.wrong_right:  # the right half is wrong: a floater
            img = img.copy()
            img[:, img.shape[1] // 2 :] = 0.5
        return img


def test_the_fixer_is_tested_leave_one_out_on_held_back_inputs_and_used_when_it_beats_both():
    from planescene import plane_scene, render_plane

    scene = plane_scene(xs=tuple(0.1 * i for i in range(12)))
    held = [2, 7, 9]
    imgs = np.stack([render_plane(scene.frames[i].pose, scene.camera(i)) for i in held])
    imgs[:, :, : imgs.shape[2] // 2] = 0.2  # the views are right on the right half only, unsure on the left
    conf = np.ones(imgs.shape[:3], np.float32)
    conf[:, :, : imgs.shape[2] // 2] = 0.1
    pairs = fixer_pairs(scene, held, _Render(scene, True), imgs, conf)
    assert pairs.names == tuple(scene.frames[i].name for i in held) and len(pairs.subset([0, 2])) == 2
    fit = validated_fixer(pairs, steps=200, seed=0)
    assert fit.record.held_back == pairs.names and fit.record.used and fit.fixer is not None
    assert fit.record.psnr_fixed > max(fit.record.psnr_view, fit.record.psnr_render)
    # a render that is right everywhere is not beaten: the fixer is not used
    plain = validated_fixer(fixer_pairs(scene, held, _Render(scene, False), imgs, conf), steps=200, seed=0)
    assert not plain.record.used and plain.fixer is None
    # one pair cannot be tested leave-one-out: no fixer
    one = validated_fixer(pairs.subset([0]), steps=200, seed=0)
    assert one.fixer is None and not one.record.used and np.isnan(one.record.psnr_fixed)


def test_each_group_is_scored_by_a_fixer_that_never_saw_its_photos():
    from dataclasses import replace

    view, render, conf, truth = _pairs(n=5)
    pairs = FixerPairs(tuple(f"p{i}" for i in range(5)), view, render, conf, truth)
    groups = [[0, 1], [2, 3], [4]]
    fit = validated_fixer(pairs, steps=20, seed=0, groups=groups)
    assert len(fit.held_out) == 3
    # other photos in the first group: its fixer is the same, the others' are not
    moved = validated_fixer(
        replace(pairs, truth=torch.where(torch.arange(5)[:, None, None, None] < 2, 1 - truth, truth)), 20, 0, groups
    )
    same = [
        all(torch.equal(p, q) for p, q in zip(a.parameters(), b.parameters()))
        for a, b in zip(fit.held_out, moved.held_out)
    ]
    assert same == [True, False, False]
    with pytest.raises(ValueError, match="do not split"):
        validated_fixer(pairs, steps=20, seed=0, groups=[[0, 1], [2, 3]])


def test_fixed_views_are_numpy_images_at_the_views_size():
    view, render, conf, _ = _pairs(n=2)
    to_np = lambda t: t.permute(0, 2, 3, 1).numpy()  # noqa: E731
    out = fixed(Fixer(), to_np(view), to_np(render), conf[:, 0].numpy())
    assert out.shape == to_np(view).shape and out.dtype == np.float32
    assert to_tensor(out).shape == view.shape


def test_the_fixers_record_round_trips_through_sparself_json():
    fx = FixerCheck(("a", "b"), 24.0, 26.5, 27.1, True)
    rec = SelfCheck(
        "3dgs", "weak", ("a", "b"), 20.5, ((1.0, 21.0),), None, 1.0, (ViewCheck("n", 1.5, 0.3, True),), "r", fx
    )
    assert SelfCheck.from_json(json.loads(json.dumps(rec.to_json()))) == rec
