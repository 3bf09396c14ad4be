"""-q shows only what a user should act on: notes that hold on every run stay out of it."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from planescene import NF, NH, NW, camera_line, noise
from sparself.capture.io.llff import llff_array
from sparself.capture.scene import Camera
from sparself.model.backbone import default_weights


def test_missing_imagenet_weights_are_a_note_not_a_warning(tmp_path, monkeypatch, caplog):
    import torch

    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    with caplog.at_level(logging.INFO, logger="sparself"):
        assert default_weights() == "none"
    said = [r for r in caplog.records if "no ImageNet weights" in r.getMessage()]
    assert len(said) == 1 and said[0].levelno == logging.INFO


@pytest.mark.parametrize("cx_shift, level", [(1.5, logging.INFO), (64.0, logging.WARNING)])
def test_llff_camera_approximation_warns_only_when_material(caplog, cx_shift, level):
    """SfM's principal point a pixel off the centre is LLFF's usual approximation (a note); 10 % off is not."""
    s = camera_line([0.0, 0.1, 0.2], (NW, NH), NF, lambda p, c, i: noise(NH, NW, i), bounds=(1.0, 5.0))
    s.cameras[1] = Camera("PINHOLE", 640, 480, (500.0, 500.0, 320 + cx_shift, 240.0))
    with caplog.at_level(logging.INFO, logger="sparself"):
        rows, _ = llff_array(s)
    said = [r for r in caplog.records if "LLFF stores one focal" in r.getMessage()]
    assert len(said) == 1 and said[0].levelno == level
    assert np.allclose(rows[:, 14], 500.0)


@pytest.mark.parametrize("focals, warned", [((500.0, 500.0, 502.0), False), ((500.0, 540.0, 580.0), True)])
def test_llff_says_when_its_loader_would_give_every_view_the_first_focal_length(caplog, focals, warned):
    """A phone's photos each get their own focal length from SfM: poses_bounds.npy keeps each, NeRF's loader
    reads the first row's for all, so a write says so where they differ by more than 1 %."""
    s = camera_line([0.0, 0.1, 0.2], (NW, NH), NF, lambda p, c, i: noise(NH, NW, i), bounds=(1.0, 5.0))
    s.cameras = {k + 1: Camera("SIMPLE_PINHOLE", 640, 480, (f, 320.0, 240.0)) for k, f in enumerate(focals)}
    for k, f in enumerate(s.frames):
        f.camera_id = k + 1
    with caplog.at_level(logging.INFO, logger="sparself"):
        rows, order = llff_array(s)
    assert np.allclose(rows[:, 14], [focals[i] for i in order])  # each row keeps its own view's focal length
    said = [r for r in caplog.records if "takes the first row's" in r.getMessage()]
    assert len(said) == int(warned) and all(r.levelno == logging.WARNING for r in said)
    if warned:
        assert "focal lengths from 500.0 to 580.0 px:" in said[0].getMessage()


def test_llff_says_when_its_loader_would_give_every_view_the_first_image_size(caplog):
    """Portrait and landscape photos in one capture: NeRF's loader would take the first row's size for all."""
    s = camera_line([0.0, 0.1], (NW, NH), NF, lambda p, c, i: noise(NH, NW, i), bounds=(1.0, 5.0))
    s.cameras = {
        1: Camera("SIMPLE_PINHOLE", 640, 480, (500.0, 320.0, 240.0)),
        2: Camera("SIMPLE_PINHOLE", 480, 640, (500.0, 240.0, 320.0)),
    }
    s.frames[1].camera_id = 2
    with caplog.at_level(logging.INFO, logger="sparself"):
        llff_array(s)
    said = [r.getMessage() for r in caplog.records if "takes the first row's" in r.getMessage()]
    assert len(said) == 1 and "these views have 2 image sizes:" in said[0]
