"""Photos as they come off phones and cameras: hidden AppleDouble files, HEIC photos,
a card's DCIM sub-folders, CMYK / grayscale / 16-bit / EXIF-rotated photos said once with a count, upright
RGB copies in a written scene, and a recovered camera that cannot be right."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sparself.capture.images import list_images, load_image, needs_conversion
from sparself.capture.io import read_scene, write_scene
from sparself.capture.photos import validate_images
from sparself.capture.scene import Camera, Frame, Scene
from sparself.cli import main
from sparself.core.errors import InputError
from sparself.core.geometry import Pose, rotmat_to_quat

W, H = 64, 48


def heif_readable() -> bool:
    from sparself.capture.images import heif_readable as _heif_readable

    return _heif_readable()


def photo(path: Path, seed: int, mode: str = "RGB", size=(W, H)) -> np.ndarray:
    """A textured RGB picture saved in ``mode``; -> the RGB uint8 pixels it was made from."""
    rgb = (np.random.default_rng(seed).random((size[1], size[0], 3)) * 255).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb).convert(mode).save(path, quality=95)
    return rgb


def apple_double(path: Path) -> None:
    """What macOS writes beside each file on FAT/exFAT: a 4 KB resource-fork header, not a picture."""
    path.write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        " + bytes(4080))


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "error:" in lines[0] and "Traceback" not in err, err
    return lines[0]


# ---- hidden files, HEIC, DCIM ------------------------------------------------------------------------------


def test_apple_double_and_hidden_files_are_skipped(tmp_path):
    for i in range(3):
        photo(tmp_path / f"IMG_000{i}.JPG", i)
        apple_double(tmp_path / f"._IMG_000{i}.JPG")
    (tmp_path / ".DS_Store").write_bytes(b"\x00\x00\x00\x01Bud1" + bytes(100))
    assert [p.name for p in list_images(tmp_path)] == ["IMG_0000.JPG", "IMG_0001.JPG", "IMG_0002.JPG"]
    assert [p.name for p in validate_images(tmp_path)] == ["IMG_0000.JPG", "IMG_0001.JPG", "IMG_0002.JPG"]


def test_only_apple_double_files_is_no_images(tmp_path, capsys):
    d = tmp_path / "photos"
    d.mkdir()
    for i in range(3):
        apple_double(d / f"._IMG_000{i}.JPG")
    code, _, err = run(capsys, "poses", d, "--out", tmp_path / "out")
    assert code == 2 and "no images found" in one_error_line(err)
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(heif_readable(), reason="pillow-heif is installed: HEIC photos are read")
def test_heic_photos_are_skipped_with_a_hint(tmp_path, caplog):
    for i in range(3):
        photo(tmp_path / f"IMG_000{i}.jpg", i)
    (tmp_path / "IMG_0100.HEIC").write_bytes(b"\x00\x00\x00\x18ftypheic" + bytes(64))
    with caplog.at_level(logging.WARNING, logger="sparself"):
        names = [p.name for p in list_images(tmp_path)]
    assert names == ["IMG_0000.jpg", "IMG_0001.jpg", "IMG_0002.jpg"]
    msg = caplog.records[-1].getMessage()
    assert "skipping 1 HEIC/HEIF photo(s) (IMG_0100.HEIC)" in msg and "heif-convert" in msg and "sips" in msg
    with pytest.raises(InputError, match="HEIC/HEIF photo that sparself cannot read; convert them to JPEG"):
        load_image(tmp_path / "IMG_0100.HEIC")


@pytest.mark.skipif(heif_readable(), reason="pillow-heif is installed: HEIC photos are read")
def test_folder_of_only_heic_photos_is_one_line_with_the_hint(tmp_path, capsys):
    d = tmp_path / "photos"
    d.mkdir()
    for i in range(4):
        (d / f"IMG_{i:04d}.HEIC").write_bytes(b"\x00\x00\x00\x18ftypheic" + bytes(64))
    code, _, err = run(capsys, "poses", d, "--out", tmp_path / "out")
    line = one_error_line(err)
    assert code == 2 and "4 HEIC/HEIF photo(s) (IMG_0000.HEIC, IMG_0001.HEIC" in line
    assert "convert them to JPEG" in line and not (tmp_path / "out").exists()


def test_photos_only_in_dcim_subfolders_are_named(tmp_path, capsys):
    card = tmp_path / "card"
    for i in range(3):
        photo(card / "DCIM" / "100APPLE" / f"IMG_{i:04d}.JPG", i)
    photo(card / "DCIM" / "101APPLE" / "IMG_0100.JPG", 9)
    apple_double(card / "DCIM" / "100APPLE" / "._IMG_0000.JPG")
    (card / "DCIM" / ".Trashes").mkdir()
    photo(card / "DCIM" / ".Trashes" / "x.jpg", 3)  # hidden folders are not offered
    with pytest.raises(InputError) as e:
        list_images(card)
    assert "sub-folder(s) DCIM/100APPLE (3 images), DCIM/101APPLE (1 images)" in str(e.value)
    assert ".Trashes" not in str(e.value)
    code, _, err = run(capsys, "poses", card, "--out", tmp_path / "out")
    line = one_error_line(err)
    assert code == 2 and f"pass one of those folders, e.g. {card / 'DCIM' / '100APPLE'}" in line


# ---- conversions: said once per folder and kind, with a count --------------------------------------------


def test_conversions_are_said_once_with_a_count(tmp_path, caplog):
    want = {}
    for i in range(3):
        want[f"g{i}.png"] = photo(tmp_path / f"g{i}.png", i, "L")
    want["c.jpg"] = photo(tmp_path / "c.jpg", 5, "CMYK")
    want["rgb.png"] = photo(tmp_path / "rgb.png", 6)
    with caplog.at_level(logging.WARNING, logger="sparself"):
        imgs = {n: load_image(tmp_path / n) for n in sorted(want)}
        again = [load_image(tmp_path / n) for n in sorted(want)]
    lines = [r.getMessage() for r in caplog.records]
    assert lines == [
        f"{tmp_path}: 1 CMYK image(s) converted to RGB: c.jpg",
        f"{tmp_path}: 3 grayscale L image(s) converted to RGB: g0.png, g1.png, g2.png",
    ], lines
    for n, rgb in want.items():
        assert imgs[n].shape == (H, W, 3) and np.array_equal(imgs[n], again[sorted(want).index(n)])
    # gray: the luma of the RGB it was made from, in all three channels
    gray = np.asarray(Image.fromarray(want["g1.png"]).convert("L"), np.float32) / 255
    np.testing.assert_allclose(imgs["g1.png"], np.repeat(gray[..., None], 3, 2), atol=1e-6)
    # CMYK JPEG: the same colours as the RGB picture it was made from (JPEG noise aside)
    assert np.abs(imgs["c.jpg"] * 255 - want["c.jpg"]).mean() < 12
    assert [needs_conversion(tmp_path / n) for n in ("g0.png", "c.jpg", "rgb.png")] == [True, True, False]


def _rotated(path: Path, seed: int) -> np.ndarray:
    """A photo stored sideways with EXIF orientation 6, as phones write them; -> its upright pixels."""
    rgb = (np.random.default_rng(seed).random((H, W, 3)) * 255).astype(np.uint8)
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(rgb).transpose(Image.Transpose.ROTATE_90).save(path, exif=exif)
    return rgb


def test_written_scene_holds_upright_rgb_copies(tmp_path):
    """write_scene (poses, synthesize and densify write through it) copies plain RGB photos byte for byte,
    and writes every other photo as upright 8-bit RGB at its camera's size with no EXIF rotation flag."""
    src = tmp_path / "src"
    src.mkdir()
    up = {
        "0.png": photo(src / "0.png", 0),
        "1.png": photo(src / "1.png", 1, "L"),
        "2.png": _rotated(src / "2.png", 2),
        "3.png": photo(src / "3.png", 3, "RGBA"),
    }
    Image.fromarray(up["0.png"][..., 0].astype(np.uint16) * 257).save(src / "4.png")
    frames = [
        Frame(f"{i}.png", Pose(np.array([1.0, 0, 0, 0]), np.array([i * 0.1, 0, 0])), 1, float(i), path=src / f"{i}.png")
        for i in range(5)
    ]
    out = tmp_path / "out"
    write_scene(Scene({1: Camera.pinhole(W, H, 50.0)}, frames), out)
    assert (out / "images" / "0.png").read_bytes() == (src / "0.png").read_bytes()
    for i in range(1, 5):
        with Image.open(out / "images" / f"{i}.png") as im:
            assert im.mode == "RGB" and im.size == (W, H) and im.getexif().get(0x0112, 1) == 1, i
    np.testing.assert_array_equal(np.asarray(Image.open(out / "images" / "2.png")), up["2.png"])
    np.testing.assert_array_equal(np.asarray(Image.open(out / "images" / "3.png")), up["3.png"])
    np.testing.assert_array_equal(np.asarray(Image.open(out / "images" / "4.png"))[..., 1], up["0.png"][..., 0])
    back = read_scene(out)
    assert all(back.load(i).shape == (H, W, 3) for i in range(5))


# ---- the pose check: jumps between capture-order neighbours ----------------------------------------------

from sparself.capture.photos import exif_focal_px  # noqa: E402
from sparself.capture.posecheck import ImageStats, camera_warnings, check_poses  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def orbit(n: int = 24, step_deg: float = 15.0, seed: int = 0) -> Scene:
    """A hand-held orbit: cameras on a slightly wobbling circle looking at the origin, with jitter."""
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        a = np.deg2rad(step_deg * i + rng.normal(0, 2))
        c = np.array([3 * np.cos(a), 0.3 * np.sin(3 * a) + rng.normal(0, 0.05), 3 * np.sin(a)])
        z = -c / np.linalg.norm(c)
        x = np.cross([0.0, -1.0, 0.0], z)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        frames.append(Frame(f"{i:02d}.png", Pose.from_center(rotmat_to_quat(R), c), 1, float(i)))
    return Scene({1: Camera.pinhole(W, H, 50.0)}, frames)


def flipped(scene: Scene, idx: list[int], deg: float = 160.0, axis=(0.3, 1.0, 0.2)) -> Scene:
    """The scene with cameras ``idx`` turned by ``deg`` about an axis through their own centres."""
    import cv2

    ax = np.asarray(axis, float) / np.linalg.norm(axis)
    Rf = cv2.Rodrigues(ax * np.deg2rad(deg))[0]
    frames = list(scene.frames)
    for i in idx:
        f = frames[i]
        frames[i] = Frame(f.name, Pose.from_center(rotmat_to_quat(Rf @ f.pose.R), f.pose.center), 1, f.index)
    return Scene(scene.cameras, frames)


def test_clean_orbit_raises_nothing():
    for step in (2.0, 15.0, 30.0):
        c = check_poses(orbit(step_deg=step, n=int(360 / step) - 1))
        assert c.suspects == [] and not c.skipped and not c.breaks, (step, c)


@pytest.mark.parametrize("step", [5.0, 15.0, 30.0])
def test_one_flipped_camera_is_named_exactly(step):
    s = flipped(orbit(n=min(24, int(360 / step) - 1), step_deg=step), [7])
    c = check_poses(s)
    assert c.names == ["07.png"], c
    assert c.suspects[0].reasons[0].startswith("looks 1") and "deg away from 06.png" in c.suspects[0].reasons[0]
    assert f"median step {c.median_rot_deg:.1f} deg" in c.suspects[0].reasons
    assert c.summary().startswith("1 suspect photo(s), poses probably wrong: 07.png (looks 1")


def test_flipped_run_and_first_camera_are_named_exactly():
    assert check_poses(flipped(orbit(), [10, 11, 12])).names == ["10.png", "11.png", "12.png"]
    assert check_poses(flipped(orbit(), [0])).names == ["00.png"]
    assert check_poses(flipped(orbit(), [23], deg=150)).names == ["23.png"]


def test_camera_moved_far_off_the_orbit_is_named():
    s = orbit()
    f = s.frames[5]
    s.frames[5] = Frame(f.name, Pose.from_center(f.pose.qvec, -f.pose.center), 1, f.index)  # mirrored centre
    c = check_poses(s)
    assert c.names == ["05.png"], c


def test_name_order_that_is_not_capture_order_uses_camera_positions():
    s = orbit()
    perm = np.random.default_rng(1).permutation(len(s))
    shuffled = Scene(s.cameras, [Frame(f"{k:02d}.png", s.frames[i].pose, 1, float(k)) for k, i in enumerate(perm)])
    c = check_poses(shuffled)
    assert c.suspects == [] and "do not follow the capture order" in c.order and not c.skipped
    # a flip is still found: it turns the view, not the centre the neighbours are taken by
    assert check_poses(flipped(shuffled, [9])).names == ["09.png"]


def mirrored_across_the_object(scene: Scene, idx: list[int]) -> Scene:
    """Cameras ``idx`` registered on the far side of the object: centre turned 180 deg about the vertical
    through the object, looking at it from there (how SfM flips a photo of a rotationally symmetric object)."""
    frames = list(scene.frames)
    for i in idx:
        f = frames[i]
        c = f.pose.center * np.array([-1.0, 1.0, -1.0])
        z = -c / np.linalg.norm(c)
        x = np.cross([0.0, -1.0, 0.0], z)
        x /= np.linalg.norm(x)
        frames[i] = Frame(f.name, Pose.from_center(rotmat_to_quat(np.stack([x, np.cross(z, x), z])), c), 1, f.index)
    return Scene(scene.cameras, frames)


def can_orbit(n: int = 25, elevation_deg: float = 15.0) -> Scene:
    """A smooth orbit of a can on a tiled floor: n photos all round, looking down at it by elevation_deg."""
    frames = []
    e = np.deg2rad(elevation_deg)
    for i in range(n):
        a = 2 * np.pi * i / n
        c = 4.0 * np.array([np.cos(e) * np.cos(a), -np.sin(e), np.cos(e) * np.sin(a)])  # y points down
        z = -c / np.linalg.norm(c)
        x = np.cross([0.0, -1.0, 0.0], z)
        x /= np.linalg.norm(x)
        frames.append(
            Frame(
                f"IMG_{i + 1}.jpg", Pose.from_center(rotmat_to_quat(np.stack([x, np.cross(z, x), z])), c), 1, float(i)
            )
        )
    return Scene({1: Camera.pinhole(W, H, 50.0)}, frames)


def test_photos_flipped_across_a_symmetric_object_are_named():
    """25 photos of a smooth orbit in name order; SfM put three of them on the far side of the object, each
    ~150 deg from both its neighbours. Their mirrored places sit between other photos, where their viewing
    directions fit, so ordering by position hides them: the names are the capture order, minus these three."""
    s = mirrored_across_the_object(can_orbit(), [4, 12, 19])
    seq = [s.frames[i].pose.R[2] for i in (3, 4, 5)]
    assert all(140 < np.degrees(np.arccos(np.clip(seq[1] @ d, -1, 1))) < 160 for d in (seq[0], seq[2]))
    c = check_poses(s)
    assert c.names == ["IMG_5.jpg", "IMG_13.jpg", "IMG_20.jpg"], c
    assert not c.order and not c.breaks
    assert all(140 <= int(r.reasons[0].split()[1]) <= 160 for r in c.suspects), c.suspects  # "looks 147 deg away"
    assert check_poses(can_orbit()).summary() == "pose check: no suspect photos"


def test_photos_on_no_path_skip_the_jump_check():
    """Cameras anywhere, looking anywhere: no order to check against, so nothing is named."""
    import cv2

    rng = np.random.default_rng(3)
    s = orbit(n=12)
    frames = [
        Frame(
            f.name,
            Pose.from_center(rotmat_to_quat(cv2.Rodrigues(rng.normal(size=3) * 2)[0]), rng.normal(size=3) * 3),
            1,
            f.index,
        )
        for f in s.frames
    ]
    c = check_poses(Scene(s.cameras, frames))
    assert c.suspects == [] and "jump check was skipped" in c.skipped, c


def test_weak_photos_from_model_statistics():
    s = orbit(n=10)
    stats = [ImageStats(f.name, 500, 4.0, 0.6) for f in s.frames]
    stats[3] = ImageStats("03.png", 40, 2.1, 0.7)  # its points are seen by it and one other photo
    stats[6] = ImageStats("06.png", 400, 3.9, 4.5)  # fits badly
    c = check_poses(s, stats)
    assert c.names == ["03.png", "06.png"]
    assert c.suspects[0].reasons == ["short tracks: its points are seen by 2.1 photos (median 4.0)"]
    assert c.suspects[1].reasons == ["reprojection error 4.50 px (median 0.60)"]


@pytest.mark.parametrize(
    "scene",
    ["llff_bird", "llff_bird25", "middlebury_templeRing", "middlebury_templeSparseRing", "middlebury_dinoSparseRing"],
)
def test_published_poses_raise_no_false_alarm(scene):
    from sparself.capture.io import read_scene

    src = DATA / scene.replace("25", "")
    if not src.is_dir():
        pytest.skip(f"{src} not available")
    s = read_scene(src)
    if scene.endswith("25"):
        s = s.subset(list(range(0, len(s), 7))[:25])
    c = check_poses(s)
    assert c.suspects == [] and not c.skipped and not c.breaks, c.summary()
    # and the detector does see a flip in the same capture
    assert check_poses(flipped(s, [len(s) // 2])).names == [s.frames[len(s) // 2].name]


# ---- the camera ----------------------------------------------------------------------------------------


def test_implausible_camera_warns_with_the_numbers():
    # the case: 8 small photos gave fx=2826, a 2.3 degree field of view (truly about 33)
    (w,) = camera_warnings(Camera("SIMPLE_RADIAL", 113, 85, (2826.0, 56.5, 42.5, 0.0)))
    assert "fx=2826 px for 113x85 photos is a 2.3 x 1.7 deg field of view" in w
    assert camera_warnings(Camera.pinhole(1600, 1200, 1400.0)) == []  # 59 deg: a phone
    # a real narrow rig (Middlebury's: 11.0 x 8.2 deg) is plausible; a 4.6 deg wide side is not
    assert camera_warnings(Camera("PINHOLE", 640, 480, (3310.4, 3325.5, 316.7, 200.6))) == []
    assert camera_warnings(Camera.pinhole(640, 480, 8000.0))
    assert "150" in " ".join(camera_warnings(Camera.pinhole(1600, 1200, 150.0))) or camera_warnings(
        Camera.pinhole(1600, 1200, 150.0)
    )  # 158 deg: fisheye-like
    (w,) = camera_warnings(Camera.pinhole(1600, 1200, 3000.0), exif_focal_px=1300.0)
    assert "fx=3000 px (29.9 deg) is far from the photos' EXIF focal length 1300 px (63.2 deg)" in w
    assert camera_warnings(Camera.pinhole(1600, 1200, 1400.0), exif_focal_px=1300.0) == []


def test_exif_focal_length_in_px(tmp_path):
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 26  # FocalLengthIn35mmFilm: a phone's main camera
    Image.new("RGB", (400, 300)).save(tmp_path / "a.jpg", exif=exif)
    Image.new("RGB", (400, 300)).save(tmp_path / "b.jpg")
    f = exif_focal_px([tmp_path / "a.jpg", tmp_path / "b.jpg"], 400, 300)
    assert f == pytest.approx(26 / np.hypot(36, 24) * 500)  # 300.4 px: a 67 deg horizontal field of view
    assert exif_focal_px([tmp_path / "b.jpg"], 400, 300) is None
    # a camera without a 35 mm equivalent: 18 mm at 4000 px per 25.4 mm (inch) of sensor, written at 6000 px
    # wide; the photo was resized to 1500x1000 since: 18 * 4000 / 25.4 * 1500 / 6000 = 708.7 px
    exif = Image.Exif()
    ifd = exif.get_ifd(0x8769)
    ifd[0x920A], ifd[0xA20E], ifd[0xA210], ifd[0xA002], ifd[0xA003] = 18.0, 4000.0, 2, 6000, 4000
    Image.new("RGB", (1500, 1000)).save(tmp_path / "c.jpg", exif=exif)
    assert exif_focal_px([tmp_path / "c.jpg"], 1500, 1000) == pytest.approx(18 * 4000 / 25.4 / 4)
    assert exif_focal_px([tmp_path / "c.jpg"], 1000, 1500) == pytest.approx(18 * 4000 / 25.4 / 4)  # upright


def test_repair_outcome_is_one_plain_sentence():
    from sparself.capture.sfm import repair_outcome

    assert (
        repair_outcome(["07.png"], [], ["a (3 pairs dropped): 24 registered, 0 suspect(s)"])
        == "tried a (3 pairs dropped): 24 registered, 0 suspect(s). repaired: 07.png now agree with their neighbours"
    )
    assert repair_outcome(["07.png", "08.png"], ["08.png"], ["a", "b"]).endswith(
        "could not repair: 08.png still look wrong; check or remove these photos (or add photos between them and "
        "their neighbours) and run again"
    )


def test_a_break_between_two_large_parts_is_reported_not_blamed():
    """Half the orbit turned: neither half is more right than the other, so no photo is named, but the
    summary (and sfm_report.json through SfmReport) says where the capture breaks."""
    from sparself.capture.sfm import SfmReport

    c = check_poses(flipped(orbit(), list(range(12, 24))))
    assert c.suspects == [] and len(c.breaks) == 1 and c.breaks[0].startswith("11.png -> 12.png: views 1"), c
    rep = SfmReport(24, [f"{i:02d}.png" for i in range(24)], [], 1, 100, 0.5, breaks=c.breaks)
    assert rep.summary().startswith(
        "registered 24 of 24 images; pose check: no suspect photos; the capture breaks at 11.png -> 12.png: views 1"
    )
    assert rep.summary().endswith("check the photos there")
