"""The fast paths give the same results as the plain ones, and the GPU options (mixed precision,
torch.compile, channels-last) are wired and run on CPU. No timings here: those are in benchmarks/run.py."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from planescene import SH as H
from planescene import SW as W
from planescene import small_plane_scene as plane_scene
from sparself.capture.scene import Frame
from sparself.core.errors import ConfigError
from sparself.core.geometry import Pose
from sparself.synthesis.run import load_run
from sparself.synthesis.synthesize import synthesize
from sparself.synthesis.train import train
from sparself.synthesis.train_config import amp_dtype

torch.set_num_threads(1)


def _targets():
    return [
        Frame(f"q{k}", Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([x * 0.08, 0, 0])), 1, x)
        for k, x in enumerate((0.5, 2.5, 3.25, 5.5, 6.2))
    ]


@pytest.fixture(scope="module")
def run(small_run):
    return small_run


def test_batched_synthesis_equals_one_target_at_a_time(run, monkeypatch):
    scene = plane_scene()
    batched = synthesize(run, scene, _targets())
    dec = run.model.decoder
    monkeypatch.setattr(dec, "tile", 8)  # images now count as "large": one target per decoder call, in tiles
    single = synthesize(run, scene, _targets())
    assert batched.shape == (5, H, W, 3)
    assert np.allclose(batched, single, atol=1e-5)
    # and a tiny voxel budget (one target per chunk) changes nothing either
    monkeypatch.setattr(dec, "tile", 256)
    monkeypatch.setattr(dec, "max_voxels", 1)
    assert np.allclose(synthesize(run, scene, _targets()), batched, atol=1e-5)


def test_amp_modes(tiny_cfg):
    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    assert amp_dtype("auto", cpu) is None and amp_dtype("auto", cuda) is torch.float16
    assert amp_dtype("bf16", cpu) is torch.bfloat16 and amp_dtype("off", cuda) is None
    with pytest.raises(ConfigError, match="amp must be one of"):
        tiny_cfg(amp="fp8")


def test_bf16_autocast_training_and_synthesis_run_on_cpu(run, tmp_path, tiny_cfg):
    """The mixed-precision code path (used on GPU) runs end to end; bf16 synthesis of a float32 run stays
    close to the float32 images."""
    scene = plane_scene()
    r = train(scene, tmp_path / "bf16", tiny_cfg(epochs=2, amp="bf16"), progress=False)
    out = synthesize(r, scene, _targets())
    assert out.dtype == np.float32 and np.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
    # a run's amp setting may change on resume (it does not change the weights' shapes)
    train(scene, tmp_path / "bf16", tiny_cfg(epochs=3, amp="off"), resume=True, progress=False)
    ref = synthesize(run, scene, _targets())
    low = load_run(run.path)
    low.cfg.amp = "bf16"
    assert np.abs(synthesize(low, scene, _targets()) - ref).mean() < 0.02


def test_compile_option_compiles_the_decoder_in_place(tmp_path, monkeypatch, tiny_cfg):
    compiled = []
    monkeypatch.setattr(torch.nn.Module, "compile", lambda self, *a, **k: compiled.append(type(self).__name__))
    r = train(plane_scene(), tmp_path / "run", tiny_cfg(epochs=1, compile=True), progress=False)
    assert compiled == ["SweepDecoder"]  # the frozen CPU backbone is not worth compiling
    assert r.cfg.compile and load_run(r.path).cfg.compile
