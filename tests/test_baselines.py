"""Classical baselines: shapes, exact cases, the synthetic plane of known depth, and no target reads."""

import dataclasses

import numpy as np
import PIL.Image
import pytest
import torch

from planescene import NUM_PLANES, plane_scene, render_plane, seen_by_all
from sparself.capture.scene import Camera, Frame
from sparself.core.geometry import Pose
from sparself.core.metrics import psnr
from sparself.synthesis.baselines import BASELINES, blend, bracketing, flow, nearest, planesweep

torch.set_num_threads(2)


def _target(x=0.3, y=0.03, index=1.5, camera_id=1, path=None):
    pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([x, y, 0.0]))
    return Frame("target", pose, camera_id, index, path)


@pytest.fixture(scope="module")
def scene():
    sc = plane_scene()
    sc.cameras[2] = Camera.pinhole(48, 32, 40.0)  # a half-size camera for targets
    return sc


@pytest.mark.parametrize("name", sorted(BASELINES))
def test_shape_range_and_target_camera_size(scene, name):
    out = BASELINES[name](scene, [_target()], num_planes=9)
    assert out.shape == (1, 64, 96, 3) and out.dtype == np.float32
    assert out.min() >= 0.0 and out.max() <= 1.0
    small = BASELINES[name](scene, [_target(0.45, 0.0, 2.25, camera_id=2)], num_planes=9)
    assert small.shape == (1, 32, 48, 3)


def test_nearest_returns_the_source_at_its_pose(scene):
    f = scene.frames[2]
    out = nearest(scene, [Frame("t", f.pose, 1, 7.0, None)])  # index is irrelevant for nearest
    np.testing.assert_array_equal(out[0], f.image)


def test_bracketing_by_index_and_fallback(scene):
    assert bracketing(scene, _target(index=1.25)) == (1, 2, pytest.approx(0.25))
    assert bracketing(scene, _target(index=2.0))[:2] == (2, 2)
    # index outside the sources' range: the two nearest by pose, t from the distances
    a, b, t = bracketing(scene, _target(x=0.25, y=0.0, index=10.0))
    assert (a, b) == (1, 2) and t == pytest.approx(0.25)
    dup = dataclasses.replace(scene, frames=[dataclasses.replace(f, index=0.0) for f in scene.frames])
    assert bracketing(dup, _target(x=0.55, y=0.0, index=0.0))[:2] == (3, 2)


def test_blend_is_the_average_at_t_half():
    sc = plane_scene(xs=(0.0, 0.0))  # identical poses, different images
    sc.frames[1].image = np.clip(1.0 - sc.frames[1].image, 0, 1)
    tg = Frame("t", sc.frames[0].pose, 1, 0.5, None)
    out = blend(sc, [tg])[0]
    np.testing.assert_allclose(out, 0.5 * (sc.frames[0].image + sc.frames[1].image), atol=1e-6)
    out = blend(sc, [dataclasses.replace(tg, index=0.25)])[0]
    np.testing.assert_allclose(out, 0.75 * sc.frames[0].image + 0.25 * sc.frames[1].image, atol=1e-6)


def test_planesweep_reproduces_the_exact_plane_warp(scene):
    tg = _target()
    gt = render_plane(tg.pose, scene.cameras[1])
    m = seen_by_all(scene, tg.pose)
    assert m.mean() > 0.5
    out = planesweep(scene, [tg], num_planes=NUM_PLANES)[0]
    assert psnr(out[m], gt[m]) > 40.0
    # the plain blend of the same neighbours is far off: the test can fail
    assert psnr(blend(scene, [tg])[0][m], gt[m]) < 25.0


def test_flow_beats_blend_on_a_translating_plane(scene):
    tg = _target(y=0.0)
    gt = render_plane(tg.pose, scene.cameras[1])
    m = seen_by_all(scene, tg.pose, margin=8.0)
    assert psnr(flow(scene, [tg])[0][m], gt[m]) > psnr(blend(scene, [tg])[0][m], gt[m]) + 2.0


def test_baselines_never_open_target_images(scene, tmp_path, monkeypatch):
    bad = tmp_path / "target.png"
    bad.write_bytes(b"not an image")
    bad.chmod(0)
    opened = []
    real_open = PIL.Image.open

    def spy(fp, *a, **k):
        opened.append(str(fp))
        return real_open(fp, *a, **k)

    monkeypatch.setattr(PIL.Image, "open", spy)
    real_builtin_open = open

    def spy_builtin(file, *a, **k):
        opened.append(str(file))
        return real_builtin_open(file, *a, **k)

    monkeypatch.setattr("builtins.open", spy_builtin)
    targets = [_target(path=bad), _target(x=0.1, index=0.5)]
    for name, fn in BASELINES.items():
        out = fn(scene, targets, num_planes=5)
        assert out.shape == (2, 64, 96, 3), name
    assert str(bad) not in opened
