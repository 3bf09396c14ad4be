"""sparself.capture.triangulate: sparse points from real photos at known poses, and the evaluation's use of them
(points from the N inputs only, the same for every row)."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest

from planescene import DEPTH, camera_line, noise, on_disk, plane_image, texture
from sparself.capture.scene import MIN_POINTS
from sparself.capture.triangulate import TriangulateConfig, Triangulated, triangulate
from sparself.core.errors import ConfigError
from sparself.evaluation import evaluate as ev
from sparself.evaluation import protocol, scene_eval
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.scene_results import InputPoints, SceneResult
from sparself.evaluation.split import make_split
from sparself.synthesis.baselines import BASELINES

SIZE, FOCAL = (240, 160), 80.0  # texture periods 10-30 px at DEPTH: enough SIFT features


def _plane(n: int = 5, step: float = 0.1, size=SIZE, focal: float = FOCAL):
    return camera_line([step * i for i in range(n)], size, focal, plane_image())


def _on_plane(points: np.ndarray, tol: float = 0.02) -> float:
    """Share of points within ``tol`` * DEPTH of the plane Z = DEPTH."""
    return float(np.mean(np.abs(points[:, 2] - DEPTH) < tol * DEPTH))


def test_points_lie_on_the_known_plane_with_its_colours():
    t = triangulate(_plane())
    assert len(t.points) >= 100 and t.points.shape[1] == 3 and t.colors.shape == t.points.shape
    assert t.views == 5 and t.pairs >= 4 and t.matches >= t.kept >= len(t.points)
    assert np.median(np.abs(t.points[:, 2] - DEPTH)) < 0.005 * DEPTH
    assert _on_plane(t.points) > 0.95
    truth = texture(t.points[:, 0], t.points[:, 1])
    assert np.median(np.abs(t.colors - truth)) < 0.03  # texture spans ~0.2-0.8
    assert np.all((t.colors >= 0) & (t.colors <= 1))


def test_large_photos_are_matched_at_the_working_size():
    # twice the size and focal length, worked on at half: the keypoints map back through the scaled camera
    t = triangulate(_plane(size=(480, 320), focal=2 * FOCAL), TriangulateConfig(max_side=240))
    assert len(t.points) >= 100 and _on_plane(t.points) > 0.95


def test_the_same_input_gives_the_same_points():
    a, b = triangulate(_plane(4)), triangulate(_plane(4))
    assert len(a.points) > 0
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.colors, b.colors)


def test_synthetic_frames_and_frames_without_a_photo_are_not_used():
    sc = _plane(6)
    # a synthetic frame whose image disagrees with the plane, and a pose without a photo
    sc.frames[2] = replace(sc.frames[2], synthetic=True, image=noise(SIZE[1], SIZE[0], 3))
    sc.frames[4] = replace(sc.frames[4], image=None, path=None)
    t = triangulate(sc)
    assert t.views == 4 and len(t.points) >= 50 and _on_plane(t.points) > 0.95
    clean = triangulate(sc.subset([0, 1, 3, 5]))
    np.testing.assert_array_equal(t.points, clean.points)


def test_too_few_views_or_matches_give_no_points(caplog):
    one = triangulate(_plane(1))
    assert one.points.shape == (0, 3) and one.colors.shape == (0, 3) and one.views == 1
    assert "at least 2" in caplog.text
    rand = camera_line([0.0, 0.1], (64, 48), 50.0, lambda pose, cam, i: noise(48, 64, i))
    t = triangulate(rand)  # unrelated images: nothing consistent to triangulate
    assert len(t.points) < 5


# ---- the evaluation --------------------------------------------------------------------------------

N_FRAMES = 24
FAR_AWAY = np.array([0.0, 0.0, 1000.0])  # planted "capture" points no input photo shows


def _capture(folder):
    sc = on_disk(
        camera_line([0.03 * i for i in range(N_FRAMES)], SIZE, FOCAL, plane_image(), name="img{:03d}.png".format),
        folder,
    )
    return replace(sc, points=FAR_AWAY + np.random.default_rng(0).normal(size=(300, 3)), source=folder)


def _run(tmp_path, scene, points: str, bounds: list | None = None):
    seen = []  # (points, synthetic frames) of every reconstructor fit
    bounds = [] if bounds is None else bounds  # and its scene's depth bounds

    class Recorder:  # a reconstructor that notes what it was fitted on; only the points matter here
        def __init__(self, sc):
            seen.append((sc.points, sum(f.synthetic for f in sc.frames)))
            bounds.append(sc.bounds)

        def render(self, pose, camera):
            return np.full((camera.height, camera.width, 3), 0.5, np.float32)

    cfg = EvalConfig(
        size=32,
        inputs=5,
        holdout_every=4,
        n_mid=2,
        n_extra=1,
        seeds=1,
        baselines=("nearest",),
        densify_baselines=("nearest",),
        synthetic_weights=(0.5, 1.0),
        examples=0,
        lpips=False,
        progress=False,
        points=points,
    )
    hooks = dict(network=lambda sc, seed: BASELINES["blend"], reconstructors={"rec": Recorder})
    res = ev.run_evaluation([scene], cfg, tmp_path / f"out-{points}", **hooks)
    s = res.scenes[0]
    assert isinstance(s, SceneResult) and s.status == "ok", s
    return s, seen, res


def test_evaluation_points_come_from_the_inputs_alone(tmp_path, monkeypatch):
    scene = _capture(tmp_path / "cap")
    split = make_split(N_FRAMES, EvalConfig(inputs=5, holdout_every=4))
    vault = tmp_path / "vault"
    vault.mkdir()
    for i in split.eval:  # held-out photos are gone: reading one outside scoring would fail the scene
        shutil.move(str(scene.frames[i].path), vault / scene.frames[i].name)
    real_truth = scene_eval.load_truth
    monkeypatch.setattr(
        scene_eval,
        "load_truth",
        lambda f, size: real_truth(replace(f, path=f.path if f.path.exists() else vault / f.path.name), size),
    )
    given = []
    real = protocol.triangulate

    def spy(sc, config=None):
        given.append([f.name for f in sc.frames])
        return real(sc, config)

    monkeypatch.setattr(protocol, "triangulate", spy)
    s, seen, res = _run(tmp_path, scene, "inputs")
    assert given == [[scene.frames[i].name for i in split.inputs]]
    assert res.settings.points == "inputs" and s.input_points is not None and s.input_points.source == "inputs"
    # N, N + sparself, weighted (choice fits and the final fit), N + nearest, oracle: every fit got them
    assert len(seen) >= 5 and {n for _, n in seen} >= {0, 3}
    first = seen[0][0]
    assert first is not None and len(first) == s.input_points.points >= MIN_POINTS
    assert _on_plane(first) > 0.9 and np.all(first[:, 2] < 100)  # none of the planted far points
    for pts, _ in seen:
        np.testing.assert_array_equal(pts, first)


def test_evaluation_can_keep_the_capture_points_and_drops_too_few(tmp_path, monkeypatch):
    scene = _capture(tmp_path / "cap")
    s, seen, res = _run(tmp_path, scene, "capture")
    assert res.settings.points == "capture" and s.input_points == InputPoints("capture", 300)
    assert all(np.array_equal(pts, scene.points) for pts, _ in seen)
    # too few points to start from, on the plane (depth DEPTH - 1 .. DEPTH + 1 from every camera on the line)
    few = np.c_[np.zeros((MIN_POINTS - 1, 2)), DEPTH + np.linspace(-1.0, 1.0, MIN_POINTS - 1)]
    monkeypatch.setattr(
        protocol, "triangulate", lambda sc, config=None: replace(Triangulated(), points=few, colors=0 * few)
    )
    bounds: list = []
    s, seen, _ = _run(tmp_path, replace(scene, bounds=None), "inputs", bounds)
    assert all(pts is None for pts, _ in seen)
    assert any("none used" in n and "bounds the scene" in n for n in s.notes)
    # ... but they bound every fit's depth: 1st / 99th percentiles of their depths from the 5 inputs, widened
    lo, hi = np.percentile(np.tile(few[:, 2], 5), [1, 99])
    assert bounds and all(b == pytest.approx((0.9 * lo, 1.1 * hi)) for b in bounds)


def test_points_option_is_validated():
    with pytest.raises(ConfigError, match="points must be one of inputs, capture"):
        EvalConfig(points="all").validate()
