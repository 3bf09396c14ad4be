"""Scene and image loading: conversions to RGB float, EXIF orientation, clear errors naming the file."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from sparself.capture.images import image_size_of, list_images, load_image
from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.errors import InputError
from sparself.core.geometry import Pose, quat_normalize


def _rgb(h=12, w=16, seed=0):
    return (np.random.default_rng(seed).random((h, w, 3)) * 255).astype(np.uint8)


def test_rgb_png_roundtrip_exact(tmp_path):
    arr = _rgb()
    Image.fromarray(arr).save(tmp_path / "a.png")
    img = load_image(tmp_path / "a.png")
    assert img.dtype == np.float32 and img.shape == (12, 16, 3)
    np.testing.assert_array_equal(np.round(img * 255).astype(np.uint8), arr)


def test_gray_rgba_16bit_become_rgb(tmp_path, caplog):
    g = _rgb()[..., 0]
    Image.fromarray(g).save(tmp_path / "g.png")
    rgba = np.dstack([_rgb(), np.full((12, 16), 7, np.uint8)])
    Image.fromarray(rgba).save(tmp_path / "a.png")
    g16 = np.arange(12 * 16, dtype=np.uint16).reshape(12, 16) * 300
    Image.fromarray(g16).save(tmp_path / "d.png")
    with caplog.at_level("WARNING"):
        ig = load_image(tmp_path / "g.png")
        ia = load_image(tmp_path / "a.png")
        i16 = load_image(tmp_path / "d.png")
    assert ig.shape == ia.shape == i16.shape == (12, 16, 3)
    np.testing.assert_allclose(ig[..., 1], g / 255.0, atol=1e-6)
    np.testing.assert_allclose(ia, rgba[..., :3] / 255.0, atol=1e-6)  # alpha dropped, not premultiplied
    np.testing.assert_allclose(i16[..., 2], g16 / 65535.0, atol=1e-6)  # 16-bit precision kept
    assert "converted to RGB" in caplog.text


def test_exif_orientation_applied(tmp_path):
    arr = _rgb(10, 20)
    im = Image.fromarray(arr)
    exif = im.getexif()
    exif[0x0112] = 6  # rotate 90 CW on display
    im.save(tmp_path / "r.jpg", exif=exif, quality=100)
    img = load_image(tmp_path / "r.jpg")
    assert img.shape == (20, 10, 3)
    assert image_size_of(tmp_path / "r.jpg") == (10, 20)


@pytest.mark.parametrize(
    "name,content,msg",
    [
        ("empty.jpg", b"", "empty"),
        ("text.jpg", b"hello, I am not an image\n", "not an image"),
    ],
)
def test_bad_files_name_the_file(tmp_path, name, content, msg):
    p = tmp_path / name
    p.write_bytes(content)
    with pytest.raises(InputError, match=msg) as e:
        load_image(p)
    assert str(p) in str(e.value)


def test_truncated_jpeg(tmp_path):
    Image.fromarray(_rgb(64, 64)).save(tmp_path / "full.jpg", quality=90)
    data = (tmp_path / "full.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="truncated|decode") as e:
        load_image(tmp_path / "cut.jpg")
    assert "cut.jpg" in str(e.value)


def test_list_images_errors(tmp_path):
    with pytest.raises(InputError, match="no such folder"):
        list_images(tmp_path / "missing")
    with pytest.raises(InputError, match="no images"):
        list_images(tmp_path)
    Image.fromarray(_rgb()).save(tmp_path / "b.png")
    Image.fromarray(_rgb()).save(tmp_path / "a.JPG")
    (tmp_path / "notes.txt").write_text("x")
    assert [p.name for p in list_images(tmp_path)] == ["a.JPG", "b.png"]


def _scene(n=5):
    cam = Camera.pinhole(32, 24, 30.0)
    frames = [
        Frame(f"{i}.png", Pose.from_center(quat_normalize([1, 0, 0.05 * i, 0]), [0.5 * i, 0, -4]), 1, float(i))
        for i in range(n)
    ]
    return Scene({1: cam}, frames)


def test_camera_intrinsics_and_resize():
    cam = Camera("SIMPLE_PINHOLE", 1280, 960, (1536.0, 640.0, 480.0))
    assert cam.fx == cam.fy == 1536.0
    h, v = cam.fov_deg
    assert abs(h - 45.24) < 0.01 and abs(v - 34.71) < 0.01
    small = cam.resized(320, 240)
    assert small.fx == pytest.approx(384.0) and small.cx == pytest.approx(160.0)
    assert small.fov_deg == pytest.approx(cam.fov_deg)
    with pytest.raises(ValueError):
        Camera("PINHOLE", 10, 10, (1.0, float("nan"), 5, 5))


def test_scene_poses_subset_scale_bounds():
    s = _scene()
    c2w = s.c2w()
    np.testing.assert_allclose(c2w[:, :3, 3], s.centers(), atol=1e-12)
    np.testing.assert_allclose(np.linalg.inv(s.w2c()), c2w, atol=1e-9)
    sub = s.subset([4, 0])
    assert [f.name for f in sub.frames] == ["4.png", "0.png"] and len(s) == 5
    assert s.scale() == pytest.approx(0.5)  # centres at x = 0, .5, .., 2: median |x - 1| = 0.5
    s.bounds = (1.0, 9.0)
    assert s.depth_bounds() == (1.0, 9.0)


def test_depth_bounds_from_points():
    s = _scene()
    # points on the plane z = 0 seen from cameras at z = -4 looking along +z: depth 4
    rng = np.random.default_rng(0)
    s.points = np.c_[rng.uniform(-1, 1, (200, 2)), np.zeros(200)]
    near, far = s.depth_bounds()
    z = np.concatenate([(s.points @ f.pose.R.T + f.pose.tvec)[:, 2] for f in s.frames])
    assert 0.8 * z.min() < near <= z.min() and z.max() <= far < 1.2 * z.max()


def test_points_depth_range_needs_ten_depths_in_front():
    from sparself.capture.scene import points_depth_range

    s = _scene()
    ahead = np.c_[np.zeros((10, 2)), np.linspace(1.0, 3.0, 10)]  # in front of every camera (at z = -4)
    near, far = points_depth_range(ahead, s.poses)
    lo, hi = np.percentile([(p.R @ x + p.tvec)[2] for p in s.poses for x in ahead], [1, 99])
    assert (near, far) == pytest.approx((0.9 * lo, 1.1 * hi))
    assert points_depth_range(ahead[:9], s.poses) is None
    assert points_depth_range(ahead - [0, 0, 10.0], s.poses) is None  # every point behind every camera


def test_scene_images_resized(tmp_path):
    s = _scene(2)
    for i, f in enumerate(s.frames):
        Image.fromarray(_rgb(24, 32, i)).save(tmp_path / f.name)
        f.path = tmp_path / f.name
    assert s.load_all().shape == (2, 24, 32, 3)
    small = s.resized(16)
    assert small.image_size() == (16, 12)
    assert small.load_all().shape == (2, 12, 16, 3)
    assert small.camera(0).fx == pytest.approx(15.0)
    s.cameras[1] = Camera.pinhole(40, 24, 30.0)
    with pytest.raises(InputError, match="camera says 40x24"):
        s.image(0)
