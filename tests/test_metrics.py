"""Metrics against hand-computed values and scikit-image."""

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from sparself.core import metrics
from sparself.core.metrics import lpips, lpips_status, psnr, ssim, summarize

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _sk(a, b):
    kw = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1)
    return structural_similarity(a, b, channel_axis=-1, **kw) if a.ndim == 3 else structural_similarity(a, b, **kw)


def test_psnr_hand_computed():
    a = np.full((8, 9, 3), 0.3)
    assert psnr(a, a + 0.1) == pytest.approx(20.0, abs=1e-9)  # MSE 0.01
    assert psnr(a * 255, (a + 0.1) * 255, max_val=255.0) == pytest.approx(20.0, abs=1e-9)
    b = a.copy()
    b[0, 0, 0] += 0.5  # MSE = 0.25 / 216
    assert psnr(a, b) == pytest.approx(10 * math.log10(216 / 0.25), abs=1e-9)


def test_psnr_identical_is_inf_and_shapes_checked():
    a = np.random.default_rng(0).random((5, 6, 3))
    assert psnr(a, a) == float("inf")
    with pytest.raises(ValueError):
        psnr(a, a[:4])


def test_ssim_identical_and_constant_images():
    a = np.random.default_rng(1).random((20, 24, 3))
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    # constant images: variances and covariance vanish, SSIM = (2 mu_a mu_b + C1) / (mu_a^2 + mu_b^2 + C1)
    c1 = 0.01**2
    expect = (2 * 0.2 * 0.4 + c1) / (0.2**2 + 0.4**2 + c1)
    assert ssim(np.full((16, 16, 3), 0.2), np.full((16, 16, 3), 0.4)) == pytest.approx(expect, abs=1e-12)


@pytest.mark.parametrize("shape", [(32, 32, 3), (23, 41, 3), (30, 17)])
def test_ssim_matches_skimage_random(shape):
    rng = np.random.default_rng(sum(shape))
    a = rng.random(shape)
    for noise in (0.02, 0.2):
        b = np.clip(a + noise * rng.standard_normal(shape), 0, 1)
        assert ssim(a, b) == pytest.approx(_sk(a, b), abs=1e-4)


def test_ssim_matches_skimage_real_pair():
    folder = DATA / "llff_bird" / "images"
    if not folder.is_dir():
        pytest.skip("shared data not present")
    from sparself.capture.images import load_image

    a = load_image(folder / "010.jpg", size=(68, 120)).astype(np.float64)
    b = load_image(folder / "012.jpg", size=(68, 120)).astype(np.float64)
    s = ssim(a, b)
    assert 0.2 < s < 0.99
    assert s == pytest.approx(_sk(a, b), abs=1e-4)


def test_lpips_unavailable_without_weights(tmp_path, monkeypatch):
    monkeypatch.delenv("SPARSELF_LPIPS_DIR", raising=False)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.setattr(
        metrics, "_candidate_dirs", lambda d, f=metrics._candidate_dirs: [p for p in f(d) if p.name != "v0.1"]
    )  # an installed lpips package must not count here
    a = np.zeros((32, 32, 3))
    assert lpips(a, a, weights_dir=tmp_path) is None
    status = lpips_status(tmp_path)
    assert status.startswith("unavailable: weights not found")
    assert str(tmp_path) in status and "alex" in status


def test_lpips_loader_plumbing_with_stand_in_files(tmp_path, monkeypatch):
    """Checks only that weight files with the published key names load and give a distance (0 for equal
    images); the values come from stand-in weights written here, so they are not LPIPS numbers."""
    import torch

    monkeypatch.delenv("SPARSELF_LPIPS_DIR", raising=False)
    g = torch.Generator().manual_seed(0)
    shapes = {0: (64, 3, 11, 11), 3: (192, 64, 5, 5), 6: (384, 192, 3, 3), 8: (256, 384, 3, 3), 10: (256, 256, 3, 3)}
    alex = {}
    for i, s in shapes.items():
        alex[f"features.{i}.weight"] = torch.randn(s, generator=g) * 0.05
        alex[f"features.{i}.bias"] = torch.zeros(s[0])
    alex["classifier.1.weight"] = torch.zeros(2, 2)  # present in torchvision's file, ignored
    lin = {
        f"lin{i}.model.1.weight": torch.rand((1, c, 1, 1), generator=g) for i, c in enumerate((64, 192, 384, 256, 256))
    }
    torch.save(alex, tmp_path / "alexnet-owt-7be5be79.pth")
    torch.save(lin, tmp_path / "alex.pth")
    assert lpips_status(tmp_path).startswith("available")
    rng = np.random.default_rng(0)
    a, b = rng.random((64, 64, 3)), rng.random((64, 64, 3))
    assert lpips(a, a, weights_dir=tmp_path) == 0.0
    d = lpips(a, b, weights_dir=tmp_path)
    assert d > 0 and d == pytest.approx(lpips(b, a, weights_dir=tmp_path), rel=1e-5)


def test_summarize():
    s = summarize([1.0, 2.0, 3.0, float("inf")])
    assert s["mean"] == 2.0 and s["min"] == 1.0 and s["max"] == 3.0 and s["n"] == 3 and s["n_inf"] == 1
    assert s["std"] == pytest.approx(math.sqrt(2 / 3))
    assert math.isnan(summarize([])["mean"])


def test_a_clear_gain_exceeds_both_its_floor_and_its_standard_error():
    assert metrics.clear_gain([1.0, 1.2, 0.8])  # mean 1.0, standard error 0.115
    assert not metrics.clear_gain([1.0, 1.2, 0.8], floor=1.0)
    # mean 0.6, sample std sqrt(3.04) = 1.744, standard error 1.007: one photo carries the mean
    assert not metrics.clear_gain([2.6, -0.6, -0.2])
    assert metrics.clear_gain([2.6, 1.4, 1.8])  # the same spread around a mean of 1.93
    assert not metrics.clear_gain([5.0]) and not metrics.clear_gain([])  # no spread to compare with


def test_a_paired_gain_is_the_difference_and_nothing_between_two_exact_scores():
    after, before = np.array([21.25, 19.5, np.inf, np.inf]), np.array([20.5, 19.5, np.inf, 30.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # inf - inf would warn and give NaN
        g = metrics.gain(after, before)
    assert g.tolist() == [0.75, 0.0, 0.0, np.inf] and g.dtype == np.float64
    assert metrics.gain([[1.0], [2.0]], [0.5, 1.0]).tolist() == [[0.5, 0.0], [1.5, 1.0]]  # broadcast
    assert float(metrics.gain(22.0, 20.5)) == 1.5
