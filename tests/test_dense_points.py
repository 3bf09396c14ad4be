"""The dense scene's sparse points: a capture without points (LLFF, transforms.json without a cloud) gets
points triangulated from its real photos at their known poses (never a synthesized or held-out view); a
capture with points keeps exactly its own."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from planescene import DEPTH, camera_line, noise_scene, on_disk, plane_image, texture
from sparself.capture import triangulate as tr
from sparself.capture.io import read_nerfstudio, read_scene, write_scene
from sparself.capture.triangulate import MIN_POINTS, ensure_points
from sparself.evaluation.selfcheck import SelfCheckConfig
from sparself.pipeline import DensifyConfig, densify
from sparself.synthesis.plan import PlanConfig

SIZE, FOCAL = (240, 160), 80.0  # the photos: enough SIFT features on the textured plane
OUT_SIZE = 48  # the written scene and training: tiny


def _capture(folder, formats) -> None:
    """6 photos of the plane Z = DEPTH on disk, posed in ``formats`` (no sparse points)."""
    scene = on_disk(
        camera_line([0.1 * i for i in range(6)], SIZE, FOCAL, plane_image(), name="p{:02d}.png".format),
        folder / "photos",
    )
    write_scene(scene, folder / "capture", formats)


def _spy(monkeypatch) -> list[list[str]]:
    """The frames (name, synthetic) of every scene triangulate() is given."""
    calls, real = [], tr.triangulate

    def spy(scene, config=None):
        calls.append([(f.name, f.synthetic) for f in scene.frames])
        return real(scene, config)

    monkeypatch.setattr(tr, "triangulate", spy)
    return calls


def _written_name(folder, source_name: str) -> str:
    """The dense scene's name of the photo ``source_name`` (sparself.json)."""
    frames = json.loads((folder / "sparself.json").read_text())["frames"]
    return next(fr["name"] for fr in frames if fr["source_name"] == source_name)


def _densify(src, out, tiny_cfg) -> None:
    cfg = DensifyConfig(
        train=tiny_cfg(epochs=1, holdout=(5,)),
        plan=PlanConfig(n_mid=2, n_extra=1),
        out_size=OUT_SIZE,
        downscaled=False,
        check=SelfCheckConfig(recon="none"),
    )
    densify(src, out, cfg)


def _reprojection_errors(scene, f) -> np.ndarray:
    """Frame f's observations against the projection of their points at its pose (px)."""
    obs = scene.observations[f.name]
    X = scene.points[obs.point] @ f.pose.R.T + f.pose.tvec
    uv = X @ scene.cameras[f.camera_id].K.T
    return np.linalg.norm(uv[:, :2] / uv[:, 2:] - obs.xy, axis=1)


@pytest.mark.parametrize("fmt", ["llff", "nerfstudio"])
def test_a_capture_without_points_is_written_with_points_from_its_real_photos(
    tmp_path, tiny_cfg, monkeypatch, caplog, fmt
):
    _capture(tmp_path, (fmt,))
    calls = _spy(monkeypatch)
    with caplog.at_level(logging.INFO, logger="sparself"):
        _densify(tmp_path / "capture", tmp_path / "out", tiny_cfg)
    # the 5 training photos at their own size: no synthesized view, not the held-out p05.png
    assert calls == [[(f"p{i:02d}.png", False) for i in range(5)]]
    folder = tmp_path / "out" / "scene"
    back = read_scene(folder)  # the COLMAP model
    n = len(back.points)
    assert n >= MIN_POINTS and f"triangulated {n} points from 5 photos" in caplog.text
    assert np.median(np.abs(back.points[:, 2] - DEPTH)) < 0.01 * DEPTH
    colors = back.point_colors / 255.0
    assert np.median(np.abs(colors - texture(back.points[:, 0], back.points[:, 1]))) < 0.05
    assert sum(f.synthetic for f in back.frames) == 3 and len(back) == 9
    # tracks: the training photos keep the keypoints the points were triangulated from (each point in at
    # least 2 of them, near its projection); the others (synthesized, held out) observe the points' projections
    obs = back.observations
    used = [f for f in back.frames if not f.synthetic and f.name != _written_name(folder, "p05.png")]
    assert len(used) == 5 and all(len(obs[f.name].point) for f in back.frames)
    seen = np.bincount(np.concatenate([obs[f.name].point for f in used]), minlength=n)
    assert seen.min() >= 2 and seen.sum() < 5 * n  # real tracks, not every point in every photo
    err = [_reprojection_errors(back, f) for f in used]
    assert all(np.median(e) < 0.2 for e in err) and max(e.max() for e in err) > 1e-3  # keypoints, not projections
    assert all(_reprojection_errors(back, f).max() < 1e-3 for f in back.frames if f not in used)
    # nerfstudio's cloud: the same points and colours
    assert json.loads((folder / "transforms.json").read_text())["ply_file_path"] == "sparse_pc.ply"
    ns = read_nerfstudio(folder / "transforms.json")
    np.testing.assert_allclose(ns.points, back.points, atol=1e-5)
    np.testing.assert_array_equal(ns.point_colors, back.point_colors)


def test_a_capture_with_points_keeps_exactly_its_own(tmp_path, tiny_cfg, monkeypatch):
    _capture(tmp_path, ("colmap",))
    rng = np.random.default_rng(1)
    pts = np.column_stack(
        [rng.uniform(-0.5, 1.0, MIN_POINTS), rng.uniform(-0.4, 0.4, MIN_POINTS), np.full(MIN_POINTS, DEPTH)]
    )
    colors = rng.integers(0, 256, (MIN_POINTS, 3), dtype=np.uint8)
    cap = read_scene(tmp_path / "capture")
    cap.points, cap.point_colors = pts, colors
    write_scene(cap, tmp_path / "with_points", ("colmap",))
    calls = _spy(monkeypatch)
    _densify(tmp_path / "with_points", tmp_path / "out", tiny_cfg)
    back = read_scene(tmp_path / "out" / "scene")
    assert calls == []
    assert len(back.points) >= MIN_POINTS  # theirs, plus one on the axis of a view that sees none
    np.testing.assert_array_equal(back.points[:MIN_POINTS], pts)
    np.testing.assert_array_equal(back.point_colors[:MIN_POINTS], colors)


def test_synthesize_gives_the_run_scene_points_from_its_training_photos(tmp_path, tiny_cfg, monkeypatch):
    from sparself.synthesis.plan import plan_poses, save_plan
    from sparself.synthesis.synthesize import synthesize_plan
    from sparself.synthesis.train import train_scene

    _capture(tmp_path, ("llff",))
    src = tmp_path / "capture"
    train_scene(src, tmp_path / "run", tiny_cfg(epochs=1, size=OUT_SIZE, holdout=(5,)))
    scene = read_scene(src)
    save_plan(tmp_path / "plan.json", plan_poses(scene, PlanConfig(n_mid=1, n_extra=0)), scene=scene)
    calls = _spy(monkeypatch)
    synthesize_plan(tmp_path / "run", tmp_path / "plan.json", tmp_path / "dense", downscaled=False)
    assert calls == [[(f"p{i:02d}.png", False) for i in range(5)]]
    back = read_scene(tmp_path / "dense")
    assert len(back.points) >= MIN_POINTS and np.median(np.abs(back.points[:, 2] - DEPTH)) < 0.01 * DEPTH
    assert (tmp_path / "dense" / "sparse_pc.ply").is_file()


def test_too_few_points_leave_the_scene_as_it_was(caplog):
    scene = noise_scene(4, size=(64, 48))  # random pixels: nothing consistent to match
    scene.points = np.zeros((MIN_POINTS - 1, 3))
    with caplog.at_level(logging.WARNING, logger="sparself"):
        assert ensure_points(scene) is scene
    assert f"(< {MIN_POINTS}): not used, the scene is written with its own {MIN_POINTS - 1}" in caplog.text


def test_too_few_points_still_bound_a_scene_without_bounds(monkeypatch):
    scene = camera_line([0.1 * i for i in range(5)], SIZE, FOCAL, plane_image(), bounds=None)
    few = np.c_[np.zeros((20, 2)), np.full(20, DEPTH)]  # 20 points, every one at depth DEPTH
    monkeypatch.setattr(tr, "triangulate", lambda sc, config=None: tr.Triangulated(points=few, colors=0 * few))
    out = ensure_points(scene)
    assert out.points is None and out.bounds == pytest.approx((0.9 * DEPTH, 1.5 * 0.9 * DEPTH))  # far >= 1.5 near
    assert scene.bounds is None  # the input is not modified
    bounded = camera_line([0.1 * i for i in range(5)], SIZE, FOCAL, plane_image(), bounds=(1.0, 2.0))
    assert ensure_points(bounded) is bounded  # known bounds win


def test_few_own_points_are_replaced_by_triangulated_ones():
    scene = camera_line([0.1 * i for i in range(5)], SIZE, FOCAL, plane_image())
    scene.points, scene.point_colors = np.zeros((3, 3)), np.zeros((3, 3), np.uint8)
    out = ensure_points(scene)
    assert len(out.points) >= MIN_POINTS and out.point_colors.shape == out.points.shape
    assert out.point_colors.dtype == np.uint8 and len(scene.points) == 3  # the input is not modified


def test_no_triangulate_reaches_densify_and_synthesize(monkeypatch):
    from sparself import cli, pipeline
    from sparself.capture.scene import Scene
    from sparself.synthesis import synthesize

    seen = {}

    def keep(key, value):
        seen[key] = value
        return Scene({}, [])

    monkeypatch.setattr(pipeline, "densify", lambda photos, out, cfg, resume=False: keep("densify", cfg.triangulate))
    monkeypatch.setattr(synthesize, "synthesize_plan", lambda *a, triangulate, **k: keep("synth", triangulate))
    for flag, want in (([], True), (["--no-triangulate"], False)):
        assert cli.main(["densify", "p", "--out", "o", "-q", *flag]) == 0
        assert cli.main(["synthesize", "r", "--plan", "x.json", "--out", "o", "-q", *flag]) == 0
        assert seen == {"densify": want, "synth": want}
