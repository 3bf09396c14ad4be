"""Shared fixtures. The synthetic scenes themselves come from ONE builder, :mod:`planescene`."""

from __future__ import annotations

import os
import signal

import pytest
import torch

from planescene import SW, noise_scene, small_plane_scene
from sparself.synthesis.train import train
from sparself.synthesis.train_config import TrainConfig

torch.set_num_threads(1)  # the test machine's cores are shared; 1 thread is faster there

# The suite's 3DGS fits are tiny (tens of pixels, tens of steps): compiling the rasterizer costs seconds in each
# process that fits, test workers, fit workers and commands alike, and saves nothing at these sizes. So the
# suite runs the plain path (children inherit it through the environment); the compiled path's own tests turn
# compiling back on (``compiled_splat``). TORCH_COMPILE_DISABLE=0 runs the whole suite compiled.
torch._dynamo.config.disable = os.environ.setdefault("TORCH_COMPILE_DISABLE", "1") == "1"

# A suite started in the background by a non-interactive shell inherits SIGINT ignored, and so would every
# command it starts: the tests that press Ctrl-C on a command would see it ignored. A Python handler here
# is reset to the default in each child at exec, so Ctrl-C reaches them again.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def make_tiny_cfg(**kw) -> TrainConfig:
    """A network small enough for the suite: the small plane scene's size, 8 planes, 4 channels."""
    base = dict(
        epochs=3,
        size=SW,
        crop=16,
        planes=8,
        channels=4,
        batch_size=3,
        fc_side=12,
        backbone_size=32,
        checkpoint_every=1,
        device="cpu",
    )
    base.update(kw)
    return TrainConfig(**base)


@pytest.fixture
def compiled_splat(monkeypatch):
    """The CPU 3DGS's compiled path (``torch.compile``), in this process and in the fit workers it spawns.
    -> ``graphs()``: how many graphs this process has compiled since (0: only the plain path ran here)."""
    from sparself.recon import splat

    monkeypatch.setenv("TORCH_COMPILE_DISABLE", "0")
    monkeypatch.setattr(splat, "_FAST", {})
    with torch._dynamo.config.patch(disable=False):
        torch._dynamo.reset()  # code run while compiling was off is marked to be skipped: forget that
        torch._dynamo.utils.counters.clear()  # what compiles from here on, and only that
        yield lambda: torch._dynamo.utils.counters["stats"]["unique_graphs"]
        torch._dynamo.reset()


@pytest.fixture
def tiny_cfg():
    """``tiny_cfg(**overrides) -> TrainConfig`` (see :func:`make_tiny_cfg`)."""
    return make_tiny_cfg


@pytest.fixture
def small_scene():
    """The 7-view small plane scene (40 x 28 px, plane at depth 2, bounds (1, 4))."""
    return small_plane_scene()


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """A run trained for 2 epochs on the small plane scene (shared by a module's tests; do not modify)."""
    return train(small_plane_scene(), tmp_path_factory.mktemp("run") / "run", make_tiny_cfg(epochs=2), progress=False)


@pytest.fixture
def noisy_scene():
    """A 6-view scene of random pixels (names 00.png..05.png), for tests of files and errors."""
    return noise_scene(6)
