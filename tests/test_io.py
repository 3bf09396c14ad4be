"""Scene formats: round trips between every pair of formats, published data read two ways, bad pose files."""

from __future__ import annotations

import itertools
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from sparself.capture.images import save_image
from sparself.capture.io import (
    detect_format,
    read_colmap,
    read_llff,
    read_middlebury,
    read_nerfstudio,
    read_scene,
    write_colmap,
    write_llff,
    write_middlebury,
    write_nerfstudio,
    write_scene,
)
from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.errors import InputError, OutputError
from sparself.core.geometry import Pose, rotmat_to_quat

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

W, H = 24, 16


def _look_at(center: np.ndarray, target=np.zeros(3), up=np.array([0.0, -1.0, 0.0])) -> Pose:
    """OpenCV camera at ``center`` looking at ``target`` (y down)."""
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world = world-to-camera rotation
    return Pose(rotmat_to_quat(R), -R @ center)


def _synthetic_scene(folder: Path, n: int = 5, seed: int = 0, focal_per_photo: bool = False) -> Scene:
    """A small orbit of n cameras around the origin with tiny random images and a few sparse points (each photo
    with its own focal length, as SfM gives a phone's zooming photos, with ``focal_per_photo``)."""
    rng = np.random.default_rng(seed)
    img_dir = folder / "images"
    img_dir.mkdir(parents=True)
    frames = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.1
        c = np.array([3 * np.cos(a), 0.3 * rng.standard_normal(), 3 * np.sin(a)])
        p = img_dir / f"{i:03d}.png"
        save_image(p, rng.random((H, W, 3)))
        frames.append(
            Frame(name=p.name, pose=_look_at(c), camera_id=i + 1 if focal_per_photo else 1, index=float(i), path=p)
        )
    cams = {
        k + 1: Camera("SIMPLE_PINHOLE", W, H, (20.5 + 3 * k, W / 2, H / 2)) for k in range(n if focal_per_photo else 1)
    }
    pts = rng.uniform(-0.5, 0.5, (50, 3))  # LLFF can hold only the SIMPLE_PINHOLE form above
    return Scene(cameras=cams, frames=frames, points=pts, bounds=None)


def _intr(cam: Camera) -> np.ndarray:
    return np.array([cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height])


def _assert_same(a: Scene, b: Scene, tol: float = 1e-6) -> None:
    assert [f.name for f in a.frames] == [f.name for f in b.frames]
    for i, (fa, fb) in enumerate(zip(a.frames, b.frames)):
        np.testing.assert_allclose(fa.pose.w2c(), fb.pose.w2c(), atol=tol, err_msg=fa.name)
        np.testing.assert_allclose(_intr(a.camera(i)), _intr(b.camera(i)), atol=tol, err_msg=fa.name)


# writer (scene, folder) -> path to read back with the matching reader
_WRITERS = {
    "colmap": lambda s, d: (write_colmap(s, d / "sparse" / "0"), read_colmap(d, d / "images"))[1],
    "llff": lambda s, d: (write_llff(s, d), read_llff(d))[1],
    "nerfstudio": lambda s, d: (write_nerfstudio(s, d), read_nerfstudio(d))[1],
    "middlebury": lambda s, d: (write_middlebury(s, d / "scene_par.txt"), read_middlebury(d))[1],
}


def _via(fmt: str, scene: Scene, folder: Path) -> Scene:
    folder.mkdir(parents=True, exist_ok=True)
    src = scene.frames[0].path.parent.resolve()
    (folder / "images").symlink_to(src, target_is_directory=True)
    if fmt == "middlebury":  # *_par.txt names images beside it
        for f in scene.frames:
            (folder / f.name).symlink_to(src / f.name)
    return _WRITERS[fmt](scene, folder)


@pytest.mark.parametrize("per_photo", [False, True], ids=["one camera", "a focal length per photo"])
@pytest.mark.parametrize("a,b", list(itertools.product(_WRITERS, repeat=2)))
def test_round_trip_between_formats(tmp_path, a, b, per_photo):
    scene = _synthetic_scene(tmp_path / "src", focal_per_photo=per_photo)
    first = _via(a, scene, tmp_path / "a")
    second = _via(b, first, tmp_path / "b")
    _assert_same(scene, first)
    _assert_same(scene, second)


def test_colmap_text_and_distortion_round_trip(tmp_path):
    scene = _synthetic_scene(tmp_path / "src")
    scene.cameras[1] = Camera("OPENCV", W, H, (20.0, 21.0, 11.5, 8.25, 0.01, -0.002, 0.001, 0.0005))
    write_colmap(scene, tmp_path / "m", text=True)
    assert (tmp_path / "m" / "images.txt").is_file()
    back = read_colmap(tmp_path / "m", scene.frames[0].path.parent)
    assert back.cameras[1] == scene.cameras[1]
    np.testing.assert_allclose(back.points, scene.points, atol=1e-9)
    write_nerfstudio(scene, tmp_path / "ns")
    (tmp_path / "ns" / "images").symlink_to(scene.frames[0].path.parent, target_is_directory=True)
    ns = read_nerfstudio(tmp_path / "ns")
    np.testing.assert_allclose(ns.cameras[1].params, scene.cameras[1].params, atol=1e-9)
    _assert_same(scene, ns)


def test_opengl_axes_in_transforms_json(tmp_path):
    """A camera at +z looking at the origin has OpenGL back axis (+z) = column 2 of transform_matrix."""
    scene = _synthetic_scene(tmp_path / "src", n=3)
    scene.frames[0] = Frame("000.png", _look_at(np.array([0.0, 0.0, 3.0])), 1, 0.0, scene.frames[0].path)
    write_nerfstudio(scene, tmp_path)
    M = np.array(json.loads((tmp_path / "transforms.json").read_text())["frames"][0]["transform_matrix"])
    np.testing.assert_allclose(M[:3, 2], [0, 0, 1], atol=1e-12)  # back = away from the origin
    np.testing.assert_allclose(M[:3, 1], [0, 1, 0], atol=1e-12)  # up = -(OpenCV down) = world +y
    np.testing.assert_allclose(M[:3, 3], [0, 0, 3], atol=1e-12)


def test_nerf_synthetic_camera_angle_x(tmp_path):
    scene = _synthetic_scene(tmp_path, n=3)
    frames = [
        {"file_path": "./images/" + f.name[:-4], "transform_matrix": (f.pose.c2w() @ np.diag([1, -1, -1, 1])).tolist()}
        for f in scene.frames
    ]
    fov = 2 * np.arctan(0.5 * W / 20.5)
    (tmp_path / "transforms_train.json").write_text(json.dumps({"camera_angle_x": fov, "frames": frames}))
    back = read_scene(tmp_path / "transforms_train.json")
    _assert_same(scene, back)


def test_write_scene_layout_and_read_back(tmp_path):
    scene = _synthetic_scene(tmp_path / "src")
    out = tmp_path / "out"
    written = write_scene(scene, out)
    for rel in (
        "images/000.png",
        "sparse/0/cameras.bin",
        "sparse/0/images.bin",
        "sparse/0/points3D.bin",
        "poses_bounds.npy",
        "transforms.json",
    ):
        assert (out / rel).is_file(), rel
    assert (out / "images" / "000.png").read_bytes() == scene.frames[0].path.read_bytes()  # copied bytes
    assert written.frames[0].path == out / "images" / "000.png"
    assert detect_format(out) == "colmap"
    for reader in (read_scene, read_llff, read_nerfstudio):
        _assert_same(scene, reader(out))
    # LLFF near/far come from the points in view: all points lie within 0.87 of the origin, cameras ~3 away
    b = np.load(out / "poses_bounds.npy")[:, 15:]
    assert np.all(b[:, 0] > 3 - 0.9 - 0.35) and np.all(b[:, 1] < 3 + 0.9 + 0.35) and np.all(b[:, 0] < b[:, 1])
    with pytest.raises(OutputError):
        write_scene(scene, out)  # refuses a non-empty folder
    with pytest.raises(OutputError, match="never writes into or over its inputs"):
        write_scene(written, out, overwrite=True, images="link")  # links to its own images, deleted by the swap
    assert (out / "images" / "000.png").read_bytes() == scene.frames[0].path.read_bytes()
    write_scene(scene, out, overwrite=True)


def test_write_scene_is_atomic(tmp_path):
    scene = _synthetic_scene(tmp_path / "src")
    scene.frames[2] = Frame("002.png", scene.frames[2].pose, 1, 2.0, path=None)  # nothing to write
    with pytest.raises(InputError, match="002.png"):
        write_scene(scene, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["src"]


def test_write_scene_in_memory_and_resized_images(tmp_path):
    scene = _synthetic_scene(tmp_path / "src")
    img = np.full((H, W, 3), 0.5, np.float32)
    scene.frames[0].image = img
    small = scene.resized(12)
    out = write_scene(small, tmp_path / "out")
    assert read_scene(tmp_path / "out").image_size(0) == (12, 8)
    np.testing.assert_allclose(out.load(0), 0.5, atol=1 / 255)


# ---- published data ---------------------------------------------------------------------------------


def _need(name: str) -> Path:
    p = DATA / name
    if not p.is_dir():
        pytest.skip(f"{p} not available")
    return p


def test_bird_colmap_and_llff_agree():
    bird = _need("llff_bird")
    a, b = read_colmap(bird), read_llff(bird)
    assert len(a) == len(b) == 184
    bb = {f.name: f for f in b.frames}
    err = max(np.abs(f.pose.w2c() - bb[f.name].pose.w2c()).max() for f in a.frames)
    assert err <= 1e-6
    assert a.frames[0].path.name == "001.jpg" and a.frames[0].index == 0
    assert b.bounds[0] == pytest.approx(0.4294, abs=1e-3) and b.bounds[1] == pytest.approx(53.86, abs=1e-2)
    assert a.points.shape == (6271, 3)
    assert b.cameras[1].fx == pytest.approx(905.89, abs=0.01)


def test_middlebury_temple_ring_reads_existing_views():
    ring = _need("middlebury_templeRing")
    s = read_scene(ring)
    assert len(s) == 19 and s.frames[0].name == "templeR0013.png" and s.frames[-1].name == "templeR0031.png"
    cam = s.cameras[1]
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (1520.4, 1525.9, 302.32, 246.87, 640, 480)
    # centre = -R^T t from the first listed existing row (templeR0013)
    row = next(ln.split() for ln in (ring / "templeR_par.txt").read_text().splitlines() if ln.startswith("templeR0013"))
    v = np.array(row[1:], float)
    np.testing.assert_allclose(s.frames[0].pose.center, -v[9:18].reshape(3, 3).T @ v[18:], atol=1e-9)


# ---- bad input ---------------------------------------------------------------------------------------


def _llff_folder(tmp_path: Path) -> Path:
    scene = _synthetic_scene(tmp_path)
    write_llff(scene, tmp_path)
    return tmp_path / "poses_bounds.npy"


def test_llff_nan_names_file(tmp_path):
    npy = _llff_folder(tmp_path)
    a = np.load(npy)
    a[2, 3] = np.nan
    np.save(npy, a)
    with pytest.raises(InputError, match=r"poses_bounds\.npy.*NaN"):
        read_scene(tmp_path)


def test_llff_complex_values_are_read_only_when_real(tmp_path):
    npy = _llff_folder(tmp_path)
    real = [f.pose.tvec for f in read_llff(npy).frames]
    a = np.load(npy).astype(np.complex128)
    np.save(npy, a)  # imaginary parts all zero: the same poses
    assert all(np.array_equal(f.pose.tvec, t) for f, t in zip(read_llff(npy).frames, real, strict=True))
    a[1, 4] += 0.5j
    np.save(npy, a)
    with pytest.raises(InputError, match=r"poses_bounds\.npy: expected real numbers, got complex"):
        read_scene(tmp_path)


def test_llff_huge_or_tiny_values_fail_the_checks_without_numpy_warnings(tmp_path):
    npy = _llff_folder(tmp_path)
    a = np.load(npy)
    for pos, value, problem in ((0, 1e308, "not orthonormal"), (4, 1e-320, "aspect differs")):
        b = a.copy()
        b[1, pos] = value  # a rotation entry; the image height
        np.save(npy, b)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(InputError, match=problem):
                read_scene(tmp_path)


@pytest.mark.parametrize("shape", [(5, 15), (5,), (5, 3, 5)])
def test_llff_wrong_shape_names_file(tmp_path, shape):
    npy = _llff_folder(tmp_path)
    np.save(npy, np.zeros(shape))
    with pytest.raises(InputError, match=r"poses_bounds\.npy.*shape"):
        read_scene(tmp_path)


def test_llff_truncated_and_count_mismatch(tmp_path):
    npy = _llff_folder(tmp_path)
    data = npy.read_bytes()
    npy.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"poses_bounds\.npy"):
        read_llff(npy)
    np.save(npy, np.zeros((4, 17)))
    with pytest.raises(InputError, match=r"4 poses but 5 images"):
        read_llff(npy)


def test_transforms_json_bad(tmp_path):
    scene = _synthetic_scene(tmp_path)
    js = write_nerfstudio(scene, tmp_path)
    d = json.loads(js.read_text())
    d["frames"][1]["transform_matrix"][0][3] = float("inf")
    js.write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"transforms\.json: frame 1.*NaN or inf"):
        read_scene(tmp_path)
    d["frames"][1]["transform_matrix"] = [[1, 0, 0], [0, 1, 0]]
    js.write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"transforms\.json: frame 1.*shape"):
        read_scene(tmp_path)
    js.write_text("{not json")
    with pytest.raises(InputError, match=r"transforms\.json: cannot parse"):
        read_scene(tmp_path)


def test_middlebury_bad_rows(tmp_path):
    scene = _synthetic_scene(tmp_path)
    par = write_middlebury(scene, tmp_path / "x_par.txt")
    lines = par.read_text().splitlines()
    lines[2] = lines[2].rsplit(" ", 1)[0] + " nan"
    par.write_text("\n".join(lines))
    with pytest.raises(InputError, match=r"x_par\.txt: line 3.*NaN"):
        read_scene(par)
    lines[2] = " ".join(lines[2].split()[:10])
    par.write_text("\n".join(lines))
    with pytest.raises(InputError, match=r"x_par\.txt: line 3 has 10 fields"):
        read_scene(par)


def test_colmap_missing_image_and_truncated_model(tmp_path):
    scene = _synthetic_scene(tmp_path)
    write_colmap(scene, tmp_path / "sparse" / "0")
    (tmp_path / "images" / "003.png").unlink()
    with pytest.raises(InputError, match=r"003\.png: image file not found"):
        read_scene(tmp_path)
    imgs = tmp_path / "sparse" / "0" / "images.bin"
    imgs.write_bytes(imgs.read_bytes()[:40])
    with pytest.raises(InputError, match=r"sparse/0"):
        read_scene(tmp_path)


def test_no_scene_found(tmp_path):
    with pytest.raises(InputError, match="no scene found"):
        read_scene(tmp_path)
    with pytest.raises(InputError, match="no such file"):
        read_scene(tmp_path / "missing")
