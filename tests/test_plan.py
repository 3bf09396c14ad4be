"""The novel-pose plan (paper section 3.2) on small in-memory scenes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.errors import ConfigError, InputError
from sparself.core.geometry import Pose, quat_angle, rotmat_to_quat
from sparself.synthesis.ordering import nearest_neighbour_order, plan_order
from sparself.synthesis.plan import PlanConfig, plan_poses, plan_sequence, save_plan
from sparself.synthesis.plan_files import load_plan


def look_at(center, target=(0.0, 0.0, 0.0), up=(0.0, -1.0, 0.0)) -> Pose:
    """COLMAP camera at ``center`` looking at ``target`` (y down)."""
    c = np.asarray(center, float)
    z = np.asarray(target, float) - c
    z /= np.linalg.norm(z)
    x = np.cross(np.asarray(up, float), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world coords -> world-to-camera rotation
    return Pose.from_center(rotmat_to_quat(R), c)


def arc_scene(n: int, sweep_deg: float = 180.0, radius: float = 4.0, jitter: float = 0.0, seed: int = 0) -> Scene:
    """n cameras on a horizontal arc around the origin, in capture order."""
    rng = np.random.default_rng(seed)
    angles = np.radians(np.linspace(0, sweep_deg, n))
    frames = []
    for i, a in enumerate(angles):
        c = np.array([radius * np.sin(a), 0.3 * np.sin(3 * a), -radius * np.cos(a)]) + jitter * rng.normal(size=3)
        frames.append(Frame(name=f"{i:03d}.jpg", pose=look_at(c), camera_id=1, index=float(i)))
    return Scene(cameras={1: Camera.pinhole(64, 48, 60.0)}, frames=frames, bounds=(1.0, 8.0))


def on_path(p: Pose, a: Pose, b: Pose, t: float) -> bool:
    """p is the LERP (centre) / SLERP (rotation) of a, b at t."""
    c_ok = np.allclose(p.center, (1 - t) * a.center + t * b.center, atol=1e-9)
    theta = quat_angle(a.qvec, b.qvec)
    r_ok = (
        abs(quat_angle(a.qvec, p.qvec) - abs(t) * theta) < 1e-7
        and abs(quat_angle(p.qvec, b.qvec) - abs(1 - t) * theta) < 1e-7
    )
    return c_ok and r_ok


def test_default_plan_for_25_views_is_8_mid_plus_2_extra():
    scene = arc_scene(25)
    planned = plan_poses(scene)
    assert len(planned) == 10
    idx = [f.index for f in planned]
    assert idx == sorted(idx)
    mids = [i for i in idx if 0 < i < 24]
    assert mids == [1.5, 4.5, 7.5, 10.5, 13.5, 16.5, 19.5, 22.5]  # evenly spread, symmetric
    assert idx[0] == pytest.approx(-0.2) and idx[-1] == pytest.approx(24.2)
    for f in planned:
        assert f.path is None and f.image is None and f.synthetic and f.camera_id == 1
    assert planned[1].name == "novel_0001.50.png"
    assert len({f.name for f in planned}) == 10


def test_planned_poses_lie_on_lerp_slerp_paths():
    scene = arc_scene(25, jitter=0.05, seed=1)
    P = scene.poses
    for f in plan_poses(scene):
        if f.index < 0:
            assert on_path(f.pose, P[1], P[0], 1.2)
        elif f.index > 24:
            assert on_path(f.pose, P[23], P[24], 1.2)
        else:
            i = int(np.floor(f.index))
            assert f.index - i == pytest.approx(0.5)
            assert on_path(f.pose, P[i], P[i + 1], 0.5)


def test_extrapolation_goes_beyond_the_ends():
    scene = arc_scene(10)
    c = scene.centers()
    planned = plan_poses(scene, PlanConfig(n_mid=0, n_extra=2))
    first, last = planned
    # past the last view along the last step, and before the first along the first step
    assert np.dot(last.pose.center - c[-1], c[-1] - c[-2]) > 0
    assert np.linalg.norm(last.pose.center - c[-1]) == pytest.approx(0.2 * np.linalg.norm(c[-1] - c[-2]))
    assert np.dot(first.pose.center - c[0], c[0] - c[1]) > 0
    assert first.index == pytest.approx(-0.2) and last.index == pytest.approx(9.2)
    # more extrapolations continue further out, alternating ends
    more = plan_poses(scene, PlanConfig(n_mid=0, n_extra=4))
    assert [round(f.index, 6) for f in more] == [-0.4, -0.2, 9.2, 9.4]


def test_counts_are_configurable_and_capped():
    scene = arc_scene(25)
    assert len(plan_poses(scene, PlanConfig(n_mid=24, n_extra=0))) == 24
    assert len(plan_poses(scene, PlanConfig(n_mid=3, n_extra=1))) == 4
    small = arc_scene(3)
    planned = plan_poses(small)  # 8 midpoints asked, only 2 gaps
    assert [f.index for f in planned] == pytest.approx([-0.2, 0.5, 1.5, 2.2])
    with pytest.raises(InputError, match="at least 3"):
        plan_poses(arc_scene(3).subset([0, 1]))
    with pytest.raises(ConfigError):
        plan_poses(scene, PlanConfig(n_mid=-1))
    with pytest.raises(ConfigError):
        plan_poses(scene, PlanConfig(order="random"))


def test_largest_gaps_option_picks_the_widest_gaps():
    scene = arc_scene(12)
    # widen gaps 2-3 and 8-9 by moving views 3.. and 9.. further around the arc
    ang = np.radians(np.r_[np.arange(3) * 10, 50 + np.arange(6) * 10, 140 + np.arange(3) * 10])
    frames = [
        Frame(f"{i:03d}.jpg", look_at([4 * np.sin(a), 0, -4 * np.cos(a)]), 1, float(i)) for i, a in enumerate(ang)
    ]
    scene = Scene(cameras=scene.cameras, frames=frames)
    planned = plan_poses(scene, PlanConfig(n_mid=2, n_extra=0, gaps="largest"))
    assert [f.index for f in planned] == [2.5, 8.5]


def test_nearest_neighbour_order_recovers_a_shuffled_capture():
    scene = arc_scene(25)
    perm = np.random.default_rng(3).permutation(25)
    shuffled = Scene(
        cameras=scene.cameras,
        frames=[Frame(f"img{k:03d}.jpg", scene.frames[i].pose, 1, float(k)) for k, i in enumerate(perm)],
    )
    nn = nearest_neighbour_order(shuffled)
    recovered = perm[nn]
    assert list(recovered) in (list(range(25)), list(range(24, -1, -1)))
    # auto detects the shuffle; capture keeps the given order
    assert list(plan_order(shuffled, "auto")) == list(nn)
    assert list(plan_order(shuffled, "capture")) == list(range(25))
    assert list(plan_order(scene, "auto")) == list(range(25))
    # the plan on the shuffled scene is the same set of poses as on the ordered one
    a = sorted(tuple(np.round(f.pose.center, 9)) for f in plan_poses(scene))
    b = sorted(tuple(np.round(f.pose.center, 9)) for f in plan_poses(shuffled))
    assert a == b
    # and its indices count positions along the path, matching the re-indexed scene
    ordered, targets = plan_sequence(shuffled)
    assert [f.index for f in ordered.frames] == list(range(25))
    assert [f.name for f in ordered.frames] == [shuffled.frames[i].name for i in plan_order(shuffled)]
    for f in targets:
        if 0 < f.index < 24:
            i = int(f.index)
            assert on_path(f.pose, ordered.frames[i].pose, ordered.frames[i + 1].pose, 0.5)


def test_indices_follow_the_frames_own_indices():
    scene = arc_scene(13).subset(list(range(0, 13, 2)))  # frames with index 0, 2, ..., 12
    planned = plan_poses(scene, PlanConfig(n_mid=6, n_extra=2))
    assert [f.index for f in planned] == pytest.approx([-0.4, 1, 3, 5, 7, 9, 11, 12.4])
    sources, _ = plan_sequence(scene)  # capture order: the scene keeps its own indices
    assert [f.index for f in sources.frames] == [f.index for f in scene.frames]


def test_identical_consecutive_poses_do_not_break():
    scene = arc_scene(5)
    frames = list(scene.frames)
    frames.insert(3, Frame("dup.jpg", frames[2].pose, 1, 2.5))
    frames = [Frame(f.name, f.pose, 1, float(k)) for k, f in enumerate(frames)]
    planned = plan_poses(Scene(cameras=scene.cameras, frames=frames), PlanConfig(n_mid=5, n_extra=2))
    assert all(np.all(np.isfinite(f.pose.w2c())) for f in planned)
    dup_mid = [f for f in planned if f.index == 2.5][0]
    assert np.allclose(dup_mid.pose.w2c(), frames[2].pose.w2c(), atol=1e-12)


def test_500_views_plan_correctly():
    scene = arc_scene(500, sweep_deg=300)
    perm = np.random.default_rng(4).permutation(500)
    shuffled = Scene(
        cameras=scene.cameras, frames=[Frame(f"{k}.jpg", scene.frames[i].pose, 1, float(k)) for k, i in enumerate(perm)]
    )
    planned = plan_poses(shuffled)
    assert len(planned) == 10
    # each midpoint sits between two views that are neighbours on the true arc
    centers = scene.centers()
    for f in planned:
        d = np.sort(np.linalg.norm(centers - f.pose.center, axis=1))
        step = np.linalg.norm(centers[1] - centers[0])
        assert d[0] <= 0.6 * step + 1e-9


def test_save_load_round_trip(tmp_path):
    scene = arc_scene(25)
    scene.source = tmp_path / "scene"
    cfg = PlanConfig(n_mid=5, n_extra=2)
    planned = plan_poses(scene, cfg)
    path = save_plan(tmp_path / "plan.json", planned, scene=scene, cfg=cfg)
    doc = json.loads(path.read_text())
    assert doc["config"]["n_mid"] == 5 and doc["source"].endswith("scene") and len(doc["frames"]) == 7
    assert np.allclose(np.array(doc["frames"][0]["c2w"]), planned[0].pose.c2w()[:3])
    back = load_plan(path, scene)
    assert [f.name for f in back] == [f.name for f in planned]
    assert [f.index for f in back] == [f.index for f in planned]
    for a, b in zip(back, planned):
        assert np.allclose(a.pose.w2c(), b.pose.w2c(), atol=1e-12) and a.path is None and a.synthetic
    assert not list(tmp_path.glob(".plan.json.tmp*"))


@pytest.mark.parametrize(
    "text, match",
    [
        ("{not json", "invalid JSON"),
        ('{"format": "something-else", "frames": []}', "not a sparself plan"),
        (
            '{"format": "sparself-plan", "frames": [{"index": 1, "qvec": [NaN, 0, 0, 0], "tvec": [0, 0, 0]}]}',
            "non-finite|NaN",
        ),
        (
            '{"format": "sparself-plan", "frames": [{"index": 1, "qvec": [1, 0, 0], "tvec": [0, 0, 0]}]}',
            "qvec must have 4",
        ),
        (
            '{"format": "sparself-plan", "frames": [{"index": 1, "qvec": [1, 0, 0, 0], "tvec": [0, 0, 0], '
            '"camera_id": 7}]}',
            "camera 7",
        ),
        (
            '{"format": "sparself-plan", "frames": [{"index": 1, "qvec": [1, 0, 0, 0], "tvec": [0, 0, 0], '
            '"c2w": [[1, 0, 0, 5], [0, 1, 0, 0], [0, 0, 1, 0]]}]}',
            "disagrees",
        ),
    ],
)
def test_bad_plan_files_raise_input_error_naming_the_file(tmp_path, text, match):
    p = tmp_path / "bad_plan.json"
    p.write_text(text)
    with pytest.raises(InputError, match=match) as e:
        load_plan(p, arc_scene(3))
    assert "bad_plan.json" in str(e.value)


def test_missing_plan_file(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_plan(tmp_path / "nope.json", arc_scene(3))
