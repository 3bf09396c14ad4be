"""Lens distortion: photos of distorted cameras are read as pinhole images, checked against COLMAP's camera
models written out by hand."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sparself.capture.images import save_image
from sparself.capture.info import scene_info
from sparself.capture.io import read_nerfstudio, read_scene, write_colmap, write_scene
from sparself.capture.io.nerfstudio import transforms_dict
from sparself.capture.scene import Camera, Frame, Observations, Scene
from sparself.core.geometry import Pose
from sparself.core.lens import pinhole_matrix, undistort_image, undistort_points
from test_plan import look_at

W, H = 64, 48


def _distort(n: np.ndarray, cam: Camera) -> np.ndarray:
    """COLMAP's forward model: normalised pinhole coordinates (M, 2) -> normalised distorted ones."""
    D, fisheye = cam.lens
    x, y = n[:, 0], n[:, 1]
    if fisheye:
        r = np.hypot(x, y)
        th = np.arctan(r)
        thd = th * (1 + D[0] * th**2 + D[1] * th**4 + D[2] * th**6 + D[3] * th**8)
        s = np.where(r > 1e-12, thd / np.maximum(r, 1e-12), 1.0)
        return n * s[:, None]
    k1, k2, p1, p2, k3, k4, k5, k6 = np.concatenate([D, np.zeros(8 - len(D))])
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], 1)


def _to_pixels(n: np.ndarray, K: np.ndarray) -> np.ndarray:
    return n * np.diag(K)[:2] + K[:2, 2]


def _to_normalised(xy: np.ndarray, K: np.ndarray) -> np.ndarray:
    return (xy - K[:2, 2]) / np.diag(K)[:2]


CAMERAS = {
    "SIMPLE_RADIAL": Camera("SIMPLE_RADIAL", W, H, (50.0, 31.0, 25.0, -0.12)),
    "RADIAL": Camera("RADIAL", W, H, (50.0, 32.0, 24.0, 0.08, -0.02)),
    "OPENCV": Camera("OPENCV", W, H, (52.0, 49.0, 32.5, 23.0, -0.1, 0.02, 0.003, -0.002)),
    "FULL_OPENCV": Camera(
        "FULL_OPENCV", W, H, (52.0, 51.0, 32.0, 24.0, -0.1, 0.02, 0.001, 0.001, 0.003, 0.01, 0.0, 0.0)
    ),
    "OPENCV_FISHEYE": Camera("OPENCV_FISHEYE", W, H, (40.0, 40.0, 32.0, 24.0, 0.05, -0.01, 0.002, 0.0)),
    "RADIAL_FISHEYE": Camera("RADIAL_FISHEYE", W, H, (40.0, 32.0, 24.0, -0.03, 0.004)),
}


@pytest.mark.parametrize("model", CAMERAS)
def test_undistorted_points_invert_the_camera_model(model):
    cam = CAMERAS[model]
    D, fisheye = cam.lens
    K_new = pinhole_matrix(cam.K, D, fisheye, (W, H))
    xy = np.random.default_rng(0).uniform([0, 0], [W, H], (200, 2))  # positions in the pinhole image
    photo_xy = _to_pixels(_distort(_to_normalised(xy, K_new), cam), cam.K)
    np.testing.assert_allclose(undistort_points(photo_xy, cam.K, D, fisheye, K_new), xy, atol=1e-4)


@pytest.mark.parametrize("model", [m for m in CAMERAS if not m.endswith("FISHEYE")])
def test_pinhole_view_is_the_widest_without_blank_corners(model):
    """Every pixel of the undistorted image sees through the photo, and it could not see wider."""
    cam = CAMERAS[model]
    D, _ = cam.lens
    K_new = pinhole_matrix(cam.K, D, False, (W, H))
    assert K_new[0, 0] / K_new[1, 1] == pytest.approx(cam.fx / cam.fy)  # pixels keep their shape
    np.testing.assert_allclose(K_new[:2, 2], [cam.cx, cam.cy])
    u, v = np.meshgrid(np.linspace(0, W, 65), np.linspace(0, H, 49))
    edge = np.stack([u.ravel(), v.ravel()], 1)
    seen = _to_pixels(_distort(_to_normalised(edge, K_new), cam), cam.K)
    assert seen.min() >= -1e-3 and (seen[:, 0] <= W + 1e-3).all() and (seen[:, 1] <= H + 1e-3).all()
    margin = np.minimum.reduce([seen[:, 0], W - seen[:, 0], seen[:, 1], H - seen[:, 1]])
    assert margin.min() < 0.05  # an edge of the photo is reached: the view is as wide as it can be


def _pattern(n: np.ndarray) -> np.ndarray:
    return 0.5 + 0.4 * np.sin(15 * n[..., 0]) * np.cos(12 * n[..., 1])


def _photo(cam: Camera) -> np.ndarray:
    """(H, W) photo of a smooth pattern painted on the rays, through the camera's lens (inverting the radial
    model by fixed-point iteration)."""
    k = cam.lens[0][0]
    v, u = np.mgrid[0:H, 0:W] + 0.5
    d = _to_normalised(np.stack([u.ravel(), v.ravel()], 1), cam.K)
    n = d.copy()
    for _ in range(100):
        n = d / (1 + k * (n**2).sum(1, keepdims=True))
    return _pattern(n).reshape(H, W).astype(np.float32)


def test_undistorted_photo_is_the_pinhole_image():
    cam = CAMERAS["SIMPLE_RADIAL"]
    D, _ = cam.lens
    K_new = pinhole_matrix(cam.K, D, False, (W, H))
    photo = _photo(cam)
    v, u = np.mgrid[0:H, 0:W] + 0.5
    truth = _pattern(_to_normalised(np.stack([u, v], -1).reshape(-1, 2), K_new)).reshape(H, W)
    got = undistort_image(photo, cam.K, D, False, K_new)
    inner = (slice(2, -2), slice(2, -2))
    assert np.abs(got - truth)[inner].max() < 0.02
    assert np.abs(photo - truth)[inner].max() > 0.1  # read as it is, the photo is not that image


def _distorted_capture(folder, cam: Camera) -> Scene:
    """A COLMAP model of 4 photos through ``cam`` with sparse points and their keypoints, written to ``folder``."""
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.4, 0.4, (40, 3))
    (folder / "images").mkdir(parents=True)
    frames, obs = [], {}
    for i in range(4):
        a = 0.3 * i
        pose = look_at([3 * np.sin(a), 0.2, -3 * np.cos(a)])
        path = folder / "images" / f"{i:02d}.png"
        save_image(path, rng.random((H, W, 3)))
        frames.append(Frame(path.name, pose, 1, float(i), path))
        cam_pts = pts @ pose.R.T + pose.tvec
        xy = _to_pixels(_distort(cam_pts[:, :2] / cam_pts[:, 2:], cam), cam.K)
        obs[path.name] = Observations(np.arange(len(pts)), xy, (W, H))
    scene = Scene({1: cam}, frames, points=pts, observations=obs)
    write_colmap(scene, folder / "sparse" / "0")
    return scene


def test_distorted_capture_reads_as_pinhole_and_writes_undistorted(tmp_path):
    cam = CAMERAS["SIMPLE_RADIAL"]
    _distorted_capture(tmp_path / "in", cam)
    scene = read_scene(tmp_path / "in")
    pin = scene.cameras[1]
    assert pin.model == "PINHOLE" and (pin.width, pin.height) == (W, H) and pin.fx < cam.fx
    for f in scene.frames:  # the keypoints are where the pinhole camera projects the points
        c = scene.points @ f.pose.R.T + f.pose.tvec
        np.testing.assert_allclose(scene.observations[f.name].xy, _to_pixels(c[:, :2] / c[:, 2:], pin.K), atol=1e-4)
    photo = np.asarray(scene.image(0))
    assert photo.shape == (H, W, 3)
    lens = scene_info(scene)["cameras"]["1"]["undistorted_from"]  # `info` names the lens it was read through
    assert lens == {"model": "SIMPLE_RADIAL", "params": list(cam.params)}
    written = write_scene(scene, tmp_path / "out", formats=("colmap",))
    back = read_scene(tmp_path / "out")
    assert back.cameras[1].model == "PINHOLE" and not back.undistort  # written undistorted: nothing left to do
    np.testing.assert_allclose(back.cameras[1].K, pin.K)
    np.testing.assert_allclose(back.image(0), photo, atol=1 / 255 + 1e-6)
    assert (written.frames[0].path).read_bytes() != scene.frames[0].path.read_bytes()
    assert scene.frames[0].path.read_bytes() == (tmp_path / "in" / "images" / "00.png").read_bytes()


def test_negligible_distortion_is_kept_as_it_is(tmp_path):
    cam = Camera("SIMPLE_RADIAL", W, H, (50.0, 32.0, 24.0, 1e-5))
    _distorted_capture(tmp_path / "in", cam)
    scene = read_scene(tmp_path / "in")
    assert scene.cameras[1] == cam and not scene.undistort


def test_distortion_that_would_crop_most_of_the_view_is_not_trusted(tmp_path, caplog):
    """SfM can fit a strong distortion to a few views' central keypoints; undistorting by it would throw away
    the photos' edges, so such a camera is read as pinhole, with a warning."""
    cam = Camera("SIMPLE_RADIAL", W, H, (50.0, 32.0, 24.0, 0.8))
    _distorted_capture(tmp_path / "in", cam)
    scene = read_scene(tmp_path / "in")
    assert scene.cameras[1] == cam and not scene.undistort
    assert "read as pinhole cameras" in caplog.text


def test_transforms_json_keeps_the_r6_radial_term(tmp_path):
    """nerfstudio's k3 multiplies r^6, as OpenCV's full model's does: read and written, it is kept."""
    (tmp_path / "images").mkdir()
    save_image(tmp_path / "images" / "a.png", np.zeros((H, W, 3)))
    meta = {"fl_x": 50.0, "fl_y": 50.0, "cx": 32.0, "cy": 24.0, "w": W, "h": H, "camera_model": "OPENCV"}
    meta |= {"k1": -0.1, "k2": 0.02, "k3": -0.004, "p1": 0.001, "p2": 0.0}
    meta["frames"] = [{"file_path": "images/a.png", "transform_matrix": np.eye(4).tolist()}]
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    cam = read_nerfstudio(tmp_path).cameras[1]
    assert cam.model == "FULL_OPENCV" and cam.params[4:9] == (-0.1, 0.02, 0.001, 0.0, -0.004)
    at_origin = Pose(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3))
    written = transforms_dict(Scene({1: cam}, [Frame("a.png", at_origin, 1, 0.0, tmp_path / "images/a.png")]))
    assert {k: written[k] for k in ("k1", "k2", "k3", "p1", "p2")} == {
        k: meta[k] for k in ("k1", "k2", "k3", "p1", "p2")
    }
