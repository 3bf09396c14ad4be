"""Per-pixel loss weights in the reconstructors (a frame's weight x its confidence map): the weighted losses
against hand-computed values, the default path unchanged, weight 0 frames ignored, and the evaluation's
choice of the synthetic-frame weight on input views only."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from kornia.metrics import ssim as kornia_ssim

from planescene import DEPTH, plane_scene
from sparself.capture.scene import Frame
from sparself.evaluation import evaluate as ev
from sparself.evaluation import scene_eval
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.results import MIN_ORACLE_GAIN_DB, NETWORK, NETWORK_WEIGHTED, SeededSets, WeightChoice
from sparself.evaluation.split import make_split
from sparself.evaluation.weighting import ValidationViews, choose_weight, validation_inputs
from sparself.recon.common import photometric_loss
from sparself.recon.nerf import fit as nerf_fit
from sparself.recon.nerf import weighted_mse
from sparself.recon.splat import SplatConfig
from sparself.recon.splat import fit as splat_fit

NERF = dict(steps=12, batch_rays=128, n_samples=8, levels=(8, 16), hidden=16, progress=False, threads=1, seed=2)


def _with_synthetic(sc, image, weight, confidence=None):
    """sc + one synthetic frame between its first two cameras, carrying ``image``."""
    f0, f1 = sc.frames[0], sc.frames[1]
    pose = replace(f0.pose, tvec=(f0.pose.tvec + f1.pose.tvec) / 2)
    new = Frame(
        "syn", pose, 1, 0.5, image=image.astype(np.float32), synthetic=True, weight=weight, confidence=confidence
    )
    return replace(sc, frames=[f0, new] + sc.frames[1:])


def test_weighted_mse_is_the_hand_computed_weighted_mean():
    pred = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.5, 0.5]])
    target = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.5, 0.5, 0.0]])
    w = torch.tensor([1.0, 0.5, 0.0])
    # squared errors summed over RGB: 1, 1, 0.25; (1 * 1 + 0.5 * 1 + 0 * 0.25) / (3 * 1.5)
    assert float(weighted_mse(pred, target, w)) == pytest.approx(1.5 / 4.5)
    assert float(weighted_mse(pred, target, torch.ones(3))) == pytest.approx(float(((pred - target) ** 2).mean()))
    assert float(weighted_mse(pred, target, torch.zeros(3))) == 0.0


def test_photometric_loss_weights_each_pixel():
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(1, 16, 16, 3, generator=g), torch.rand(1, 16, 16, 3, generator=g)
    plain = photometric_loss(a, b, 0.2)
    ssim = kornia_ssim(a.permute(0, 3, 1, 2), b.permute(0, 3, 1, 2), 11).mean()
    assert float(plain) == pytest.approx(float(0.8 * (a - b).abs().mean() + 0.2 * (1 - ssim)))
    assert float(photometric_loss(a, b, 0.2, torch.ones(16, 16))) == pytest.approx(float(plain), rel=1e-6)
    w = torch.zeros(16, 16)
    w[:, :8] = 0.5  # L1 only: the mean over all pixels of 0.5 x the left half's error
    expect = 0.5 * (a - b)[:, :, :8].abs().sum() / (16 * 16 * 3)
    assert float(photometric_loss(a, b, 0.0, w)) == pytest.approx(float(expect))
    assert float(photometric_loss(a, a, 0.2, w)) == pytest.approx(0.0, abs=1e-6)


def test_pixel_weight_is_frame_weight_times_confidence_at_the_camera_size():
    sc = plane_scene(xs=(0.0, 0.2))
    assert sc.pixel_weight(0) is None  # the default: every pixel counts 1
    h, w = sc.cameras[1].height, sc.cameras[1].width
    sc2 = _with_synthetic(sc, sc.frames[0].image, 0.5)
    np.testing.assert_array_equal(sc2.pixel_weight(1), np.full((h, w), 0.5, np.float32))
    conf = np.zeros((h // 2, w // 2), np.float32)
    conf[:, w // 4 :] = 1.0  # right half confident, at half resolution
    pw = _with_synthetic(sc, sc.frames[0].image, 0.5, conf).pixel_weight(1)
    assert pw.shape == (h, w)
    assert np.allclose(pw[:, : w // 2 - 2], 0.0) and np.allclose(pw[:, w // 2 + 2 :], 0.5)


def _nerf_render(sc):
    r = nerf_fit(sc, **NERF)
    return r.render(sc.frames[0].pose, sc.cameras[1])


def test_nerf_default_path_unchanged_and_weight_one_maps_match_it():
    sc = plane_scene(xs=(0.0, 0.2, 0.4))
    plain = _nerf_render(sc)
    np.testing.assert_array_equal(plain, _nerf_render(sc))  # the seed fixes the default path
    h, w = sc.cameras[1].height, sc.cameras[1].width
    ones = replace(sc, frames=[replace(f, confidence=np.ones((h, w), np.float32)) for f in sc.frames])
    assert ones.pixel_weight(0) is not None  # the weighted path, with every weight 1: the same fit
    np.testing.assert_allclose(_nerf_render(ones), plain, atol=1e-4)


@pytest.mark.parametrize("which", ["nerf", "splat"])
def test_a_weight_0_synthetic_frame_does_not_move_the_fit(which):
    sc = plane_scene(xs=(0.0, 0.2, 0.4))
    rng = np.random.default_rng(1)
    a = _with_synthetic(sc, rng.random(sc.frames[0].image.shape), 0.0)
    b = _with_synthetic(sc, rng.random(sc.frames[0].image.shape), 0.0)
    c = _with_synthetic(sc, rng.random(sc.frames[0].image.shape), 1.0)
    if which == "nerf":
        fit = _nerf_render
    else:
        sc.points = np.stack([rng.uniform(-0.7, 0.9, 300), rng.uniform(-0.5, 0.5, 300), np.full(300, DEPTH)], 1)
        a, b, c = (replace(x, points=sc.points) for x in (a, b, c))
        cfg = SplatConfig(
            steps=20,
            init_points=200,
            grow_every=5,
            grow_from=0.2,
            grow_until=0.8,
            max_gaussians=400,
            progress=False,
            seed=3,
            min_steps_per_view=0,
            threads=1,
        )

        def fit(s):
            return splat_fit(s, cfg).render(s.frames[0].pose, s.cameras[1])

    ra = fit(a)
    np.testing.assert_array_equal(ra, fit(b))  # its pixels do not matter
    assert not np.array_equal(ra, fit(c))  # and they would at weight 1


class _Renderer:
    """'Fit': the mean image of the frames (weighted by frame weight), rendered everywhere."""

    def __init__(self, sc):
        wts = np.array([f.weight for f in sc.frames])
        self.img = np.tensordot(wts, np.stack([sc.load(i) for i in range(len(sc))]), 1) / wts.sum()

    def render(self, pose, camera):
        return self.img


def test_choose_weight_picks_the_weight_that_renders_held_back_inputs_best():
    sc = plane_scene(xs=np.linspace(0, 0.9, 10))
    truth = sc.frames[0].image
    planned = [Frame(f"p{k}", sc.frames[k].pose, 1, k + 0.5) for k in range(3)]
    # synthesized views far off the inputs: the smallest weight fits the held-back inputs best
    bad = np.zeros((3,) + truth.shape, np.float32)
    views = ValidationViews(bad, None, [f.name for f in sc.without([2, 7]).frames])
    choice = choose_weight(sc, planned, views, (1.0, 0.25, 0.5), _Renderer)
    assert choice.weight == 0.25 and choice.validation_views == ["src2", "src7"]
    assert choice.validation_psnr["0.25"] > choice.validation_psnr["0.5"] > choice.validation_psnr["1.0"]
    assert validation_inputs(25) == [2, 7, 12, 17, 22] and validation_inputs(3) == [1]


def test_evaluate_reports_the_weighted_variant_without_reading_held_out_photos(tmp_path, monkeypatch):
    """Held-out images exist only inside scoring (elsewhere their frames have no pixels): the weighted fits
    and their weight choice run, are recorded, shared against the oracle and shown in the report."""
    from planescene import camera_line, plane_image

    scene = camera_line(np.linspace(0, 0.69, 24), (32, 24), 26.0, plane_image())
    cfg = EvalConfig(
        size=32,
        inputs=5,
        holdout_every=4,
        n_mid=2,
        n_extra=1,
        seeds=2,
        baselines=("blend",),
        densify_baselines=(),
        examples=0,
        lpips=False,
        progress=False,
        synthetic_weights=(0.5, 1.0),
    )
    held = {scene.frames[i].name: scene.frames[i].image for i in make_split(24, cfg).eval}
    scene = replace(scene, frames=[replace(f, image=None) if f.name in held else f for f in scene.frames])
    real_load = scene_eval.load_truth
    monkeypatch.setattr(
        scene_eval, "load_truth", lambda f, size: held[f.name] if f.name in held else real_load(f, size)
    )

    def network(sc, seed):
        from sparself.synthesis.baselines import BASELINES
        from sparself.synthesis.synthesize import Synthesized

        def synth(s, targets):
            imgs = BASELINES["blend"](s, targets)
            return Synthesized(imgs, np.full(imgs.shape[:3], 0.5, np.float32))

        return synth

    res = ev.evaluate([scene], tmp_path / "out", cfg, network=network, reconstructors={"mean": _Renderer})
    d = res.ok[0].densification["mean"]
    assert d.status == "ok", d.error
    wd = d.rows[NETWORK_WEIGHTED]
    assert isinstance(wd, SeededSets) and [p.seed for p in wd.per_seed] == [0, 1] and wd.views == 8
    sel = wd.per_seed[0].decision
    assert isinstance(sel, WeightChoice) and sel.weight in (0.5, 1.0) and sel.confidence
    assert set(sel.validation_psnr) == {"0.5", "1.0"}
    assert d.shares.get(NETWORK_WEIGHTED) is not None or (d.oracle_gain_db or 1) < MIN_ORACLE_GAIN_DB
    md = (tmp_path / "out" / "report.md").read_text()
    assert "N + sparself, weighted" in md and "synthetic-frame weight" in md
    assert "mean: N + sparself, weighted (confidence x the chosen synthetic-frame weight) vs unweighted:" in md
    off = ev.evaluate(
        [scene], tmp_path / "off", replace(cfg, weighted=False), network=network, reconstructors={"mean": _Renderer}
    )
    assert NETWORK_WEIGHTED not in off.ok[0].densification["mean"].rows


def test_mpi_blend_counts_each_pixel_by_its_reference_weight():
    """At the reference pose (identity warp), a per-pixel weight scales that MPI's colour and coverage."""
    from sparself.recon.mpi import MpiConfig, render_mpi
    from sparself.recon.mpi import fit as mpi_fit

    sc = plane_scene(xs=(0.0, 0.2, 0.4))
    cam, pose = sc.cameras[1], sc.frames[1].pose
    m = mpi_fit(sc, MpiConfig(num_planes=8)).mpi(1)
    col, cov = render_mpi(m, pose, cam.K, (cam.height, cam.width))
    wmap = torch.ones(1, cam.height, cam.width)
    wmap[:, :, : cam.width // 2] = 0.25
    col_w, cov_w = render_mpi(replace(m, weight=wmap), pose, cam.K, (cam.height, cam.width))
    inner = (slice(None), slice(2, -2), slice(2, -2))  # away from the border's bilinear falloff
    np.testing.assert_allclose(
        (col_w / col.clamp_min(1e-9))[inner].numpy(), wmap.expand(3, -1, -1)[inner].numpy(), atol=1e-4
    )
    np.testing.assert_allclose((cov_w / cov.clamp_min(1e-9))[inner].numpy(), wmap[inner].numpy(), atol=1e-4)
    # through the renderer: a weighted frame's map reaches its MPI, and a uniform weight leaves the blend's image
    # as is (the weighted sweeps are not scale free: each reference counts fully in its own MPI)
    h, w = cam.height, cam.width
    halves = replace(sc, frames=[replace(f, weight=0.5) for f in sc.frames])
    assert torch.equal(mpi_fit(halves, MpiConfig(num_planes=8)).mpi(1).weight, torch.full((1, h, w), 0.5))
    blend_only = MpiConfig(num_planes=8, weighted_sweeps=False)
    np.testing.assert_allclose(
        mpi_fit(halves, blend_only).render(pose, cam), mpi_fit(sc, blend_only).render(pose, cam), atol=1e-5
    )


def test_merge_seeds_keeps_each_units_weighted_fit_and_its_choice():
    from pathlib import Path

    from sparself.batch import merge_seeds
    from sparself.evaluation.results import FrameScore, ReconResult, ScoredSet, SeededSets
    from sparself.evaluation.scene_results import SceneResult

    def unit(seed, psnr):
        def sets(p, decision=None):
            return SeededSets([ScoredSet([FrameScore("f", 3, p, 0.5, None)], seed=seed, views=8, decision=decision)])

        choice = WeightChoice(0.25 * (seed + 1), {}, [], None, True, chosen_on_seed=seed)
        one = ScoredSet([FrameScore("f", 3, 20.0, 0.5, None)], views=5)
        orc = ScoredSet([FrameScore("f", 3, 24.0, 0.5, None)], views=8)
        rows = {"base": one, "oracle": orc, NETWORK: sets(psnr), NETWORK_WEIGHTED: sets(psnr + 1, choice)}
        return SceneResult("cap", densification={"nerf": ReconResult(rows)})

    merged = merge_seeds([(1, unit(1, 22.0), Path("seed1")), (0, unit(0, 21.0), Path("seed0"))])
    m = merged.to_json()["densification"]["nerf"]  # as the batch's results.json has it
    wd = m[NETWORK_WEIGHTED]
    assert [p["seed"] for p in wd["per_seed"]] == [0, 1]
    assert [p["selection"]["weight"] for p in wd["per_seed"]] == [0.25, 0.5]
    assert wd["summary"]["psnr"]["mean"] == pytest.approx(22.5) and wd["summary"]["psnr"]["n_seeds"] == 2
    assert m["oracle_share_weighted"] == pytest.approx(2.5 / 4) and m["oracle_share"] == pytest.approx(1.5 / 4)


def test_weighting_options_on_the_command_line():
    import argparse

    from sparself.core.errors import ConfigError
    from sparself.core.options import add_options, from_args

    p = argparse.ArgumentParser()
    add_options(p, EvalConfig, skip=("train",))
    cfg = from_args(EvalConfig, p.parse_args(["--synthetic-weights", "0.25,1"]), skip=("train",))
    assert cfg.synthetic_weights == (0.25, 1.0) and cfg.weighted
    assert not from_args(EvalConfig, p.parse_args(["--no-weighted"]), skip=("train",)).weighted
    with pytest.raises(ConfigError, match="synthetic_weights"):
        EvalConfig(synthetic_weights=(-1.0,)).validate()
    EvalConfig(synthetic_weights=(), weighted=False).validate()  # nothing to choose when it is off
