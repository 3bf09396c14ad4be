"""Capture order from file names compares numbers as numbers: phones and video exports name frames
IMG_1 ... IMG_12 without zero padding, and text order (IMG_1, IMG_10, IMG_11, IMG_12, IMG_2, ...) would
scramble every step that follows the capture (plan, info, the evaluation's held-out frames)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from planescene import NF, NH, NW, camera_line, noise
from sparself.capture.images import list_images, save_image
from sparself.capture.io import read_scene
from test_bad_input import run, write_posed

N = 12
NAMES = [f"IMG_{i + 1}.png" for i in range(N)]


def _scene(xs):
    return camera_line(
        xs, (NW, NH), NF, lambda pose, cam, i: noise(NH, NW, i), bounds=(1.0, 5.0), name=lambda i: NAMES[i]
    )


def test_photos_are_listed_in_capture_order(tmp_path):
    for n in reversed(NAMES):
        save_image(tmp_path / n, noise(8, 8, 0))
    assert [p.name for p in list_images(tmp_path)] == NAMES


@pytest.mark.parametrize("fmt", ["colmap", "llff", "nerfstudio"])
def test_scenes_are_read_in_capture_order(tmp_path, fmt):
    folder = write_posed(tmp_path / "scene", _scene([0.1 * i for i in range(N)]), fmt)
    scene = read_scene(folder)
    assert [f.name for f in scene.frames] == NAMES
    assert [f.index for f in scene.frames] == list(range(N))
    # each photo keeps its own pose (LLFF's rows follow the files in plain text order)
    assert np.allclose([f.pose.center[0] for f in scene.frames], [0.1 * i for i in range(N)])


def test_plan_follows_unpadded_names_without_a_word(tmp_path, capsys):
    folder = write_posed(tmp_path / "scene", _scene([0.1 * i for i in range(N)]), "colmap")
    code, _, err = run(capsys, "plan", folder, "--out", tmp_path / "plan.json", "-q")
    assert code == 0 and err == "", err
    plan = json.loads((tmp_path / "plan.json").read_text())
    xs = sorted(round(f["c2w"][0][3], 6) for f in plan["frames"] if 0 <= f["index"] <= N - 1)
    assert all(round(x * 100) % 10 == 5 for x in xs)  # midpoints between capture neighbours: 0.05, 0.15, ...


@pytest.mark.parametrize("order", ["auto", "capture"])
def test_names_that_disagree_with_the_positions_are_reported_even_with_q(tmp_path, capsys, order):
    rng = np.random.default_rng(0)
    folder = write_posed(tmp_path / "scene", _scene(list(rng.permutation(N) * 0.1)), "colmap")
    code, _, err = run(capsys, "plan", folder, "--out", tmp_path / "plan.json", "--order", order, "-q")
    assert code == 0
    lines = [ln for ln in err.splitlines() if ln.startswith("WARNING:")]
    assert len(lines) == 1 and "names and camera positions disagree" in lines[0], err
    assert ("following the positions" in lines[0]) == (order == "auto")


def test_info_summarises_one_camera_per_photo_and_lists_them_in_json(tmp_path, capsys):
    """Phones vary the focal length, so SfM gives each photo its camera: one line with the ranges, not 12
    blocks (and the median step follows the capture order IMG_1, IMG_2, ...)."""
    from sparself.capture.scene import Camera

    s = _scene([0.1 * i for i in range(N)])
    s.cameras = {i + 1: Camera.pinhole(NW, NH, 20.0 + i) for i in range(N)}
    for i, f in enumerate(s.frames):
        f.camera_id = i + 1
    folder = write_posed(tmp_path / "scene", s, "colmap")
    code, out, _ = run(capsys, "info", folder)
    assert code == 0
    cams = [ln for ln in out.splitlines() if ln.startswith(("cameras:", "camera 1"))]
    assert cams == [f"cameras:       {N} cameras (PINHOLE), fx 20–31 px, fy 20–31 px (--json lists each)"], out
    assert "median step:   0.1 between consecutive views" in out
    code, out, _ = run(capsys, "info", folder, "--json")
    assert sorted(round(c["fx"]) for c in json.loads(out)["cameras"].values()) == list(range(20, 32))
