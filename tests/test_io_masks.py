"""A dense scene's confidence masks come back with it: written by ``write_scene`` (``masks/<stem>.png``,
transforms.json's ``mask_path``), read by ``read_scene`` in every format sparself writes, as each frame's
``mask`` that ``Scene.pixel_weight`` reads. A mask value m reads as m / 255 = round(255 c) / 255, and 0 where
the confidence was below MASK_FLOOR; real photos (all-255 masks) come back with no map."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from planescene import camera_line, noise, on_disk
from sparself.capture.io import DenseInfo, read_scene, write_scene
from sparself.capture.io.dense import MASK_FLOOR
from sparself.capture.scene import Frame, Scene
from sparself.cli import main
from sparself.core.errors import InputError
from sparself.core.geometry import interpolate_pose

W, H = 14, 10


def _confidence(seed: int) -> np.ndarray:
    """A known map (H, W) in [0, 1] with values at and around the floor, 0 and 1."""
    c = np.random.default_rng(seed).uniform(0.0, 1.0, (H, W)).astype(np.float32)
    c[0, :5] = [0.0, MASK_FLOOR - 0.01, MASK_FLOOR + 0.001, 0.5, 1.0]
    return c


def _dense(folder: Path) -> Scene:
    """5 photos on disk + 2 synthesized views (in memory, with confidence maps) between them."""
    scene = on_disk(
        camera_line(
            [0.1 * i for i in range(5)],
            (W, H),
            12.0,
            lambda pose, cam, i: noise(H, W, i),
            bounds=(1.0, 5.0),
            name=lambda i: f"{i:02d}.png",
        ),
        folder,
    )
    syn = [
        Frame(
            f"novel_{k}.png",
            interpolate_pose(scene.frames[k].pose, scene.frames[k + 1].pose, 0.5),
            index=k + 0.5,
            image=noise(H, W, 10 + k),
            synthetic=True,
            confidence=_confidence(k),
        )
        for k in (1, 2)
    ]
    return replace(scene, frames=sorted(scene.frames + syn, key=lambda f: f.index))


@pytest.fixture(scope="module")
def dense(tmp_path_factory):
    """The written dense scene (all formats, with images_2/4/8 and masks_2/4/8) and its folder."""
    tmp = tmp_path_factory.mktemp("masks")
    written = write_scene(_dense(tmp / "src"), tmp / "out")
    return written, tmp / "out"


READS = {
    "colmap": lambda d: read_scene(d),
    "llff": lambda d: read_scene(d / "poses_bounds.npy"),
    "nerfstudio": lambda d: read_scene(d / "transforms.json"),
}


@pytest.mark.parametrize("fmt", sorted(READS))
def test_confidence_comes_back_in_every_format(dense, fmt):
    written, folder = dense
    scene = READS[fmt](folder)
    assert scene.source_format == fmt
    conf = {f.name: f.confidence for f in written.frames}
    assert sorted(f.name for f in scene.frames) == sorted(conf)
    for i, f in enumerate(scene.frames):
        assert f.confidence is None  # kept on disk, read when used
        if conf[f.name] is None:  # a real photo: its all-255 mask is no map, the plain loss
            assert f.mask is None and not f.synthetic and scene.pixel_weight(i) is None
            continue
        c = conf[f.name]
        assert f.synthetic and f.mask == folder / "masks" / (Path(f.name).stem + ".png")
        got = scene.confidence_map(i)
        assert got.shape == (H, W) and got.dtype == np.float32
        low = c < MASK_FLOOR
        assert (got[low] == 0).all() and (got[~low] > 0).all()
        assert np.abs(got[~low] - c[~low]).max() <= 0.5 / 255 + 1e-6  # round(255 c) / 255
        assert np.abs(got * 255 - np.round(got * 255)).max() < 1e-4  # 8-bit levels


def test_pixel_weight_is_weight_times_the_read_confidence(dense):
    _, folder = dense
    scene = read_scene(folder)
    i = next(k for k, f in enumerate(scene.frames) if f.synthetic)
    conf = scene.confidence_map(i)
    np.testing.assert_array_equal(scene.pixel_weight(i), conf)  # weight 1: the map itself
    scene.frames[i].weight = 0.25
    np.testing.assert_allclose(scene.pixel_weight(i), 0.25 * conf, atol=1e-7)
    small = scene.resized(7)  # a resized scene reads the map at its camera's size (area mean when shrinking)
    pw = small.pixel_weight(i)
    assert pw.shape == (5, 7)
    np.testing.assert_allclose(pw, 0.25 * conf.reshape(5, 2, 7, 2).mean((1, 3)), atol=1e-6)


def test_downscaled_images_bring_their_downscaled_masks(dense):
    _, folder = dense
    full = read_scene(folder / "poses_bounds.npy")
    half = read_scene(folder / "poses_bounds.npy", images=folder / "images_2")
    assert sum(f.mask is not None for f in half.frames) == 2
    for i, f in enumerate(half.frames):
        assert (f.mask is None) == (full.frames[i].mask is None)
        if f.mask is not None:
            assert f.mask.parent.name == "masks_2" and half.confidence_map(i).shape == (H // 2, W // 2)
            full_mask = Image.fromarray(np.asarray(Image.open(full.frames[i].mask)))
            nearest = np.asarray(full_mask.resize((W // 2, H // 2), Image.NEAREST), np.float32) / 255
            np.testing.assert_array_equal(half.confidence_map(i), nearest)


def test_a_dense_scene_written_again_keeps_its_masks(dense, tmp_path):
    _, folder = dense
    again = write_scene(read_scene(folder), tmp_path / "again", dense=DenseInfo(downscale=False))
    for f in again.frames:
        a = np.asarray(Image.open(folder / "masks" / (Path(f.name).stem + ".png")))
        assert np.array_equal(np.asarray(Image.open(tmp_path / "again" / "masks" / (Path(f.name).stem + ".png"))), a)


def test_masks_are_read_only_when_every_image_has_one(dense, tmp_path, caplog):
    import shutil

    _, folder = dense
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy, symlinks=True)
    victim = next(p for p in sorted((copy / "masks").iterdir()) if "novel" in p.name)
    victim.unlink()
    scene = read_scene(copy)  # COLMAP: a partial masks/ folder is not a dense scene's; no map at all
    assert all(f.mask is None for f in scene.frames) and "masks for 6 of 7 images" in caplog.text


def _broken(folder: Path, tmp_path: Path, how: str) -> tuple[Path, Path]:
    """A copy of the scene with only transforms.json, one synthesized view's mask made bad."""
    import shutil

    copy = tmp_path / how
    shutil.copytree(folder / "images", copy / "images")
    shutil.copytree(folder / "masks", copy / "masks")
    shutil.copy(folder / "transforms.json", copy)
    doc = json.loads((copy / "transforms.json").read_text())
    mask = copy / next(fr["mask_path"] for fr in doc["frames"] if fr["synthetic"])
    if how == "missing":
        mask.unlink()
    elif how == "corrupt":
        mask.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    else:
        Image.new("L", (W + 1, H), 128).save(mask)
    return copy, mask


@pytest.mark.parametrize(
    "how,problem",
    [
        ("missing", "no such mask file"),
        ("corrupt", "mask is not an image file"),
        ("size", f"mask is {W + 1}x{H} but its image is {W}x{H}"),
    ],
)
def test_a_bad_mask_named_by_transforms_json_is_one_line_naming_it(dense, tmp_path, capsys, how, problem):
    _, folder = dense
    copy, mask = _broken(folder, tmp_path, how)
    with pytest.raises(InputError, match=problem) as e:
        read_scene(copy)
    assert str(e.value).startswith(str(mask))
    code = main(["info", str(copy)])
    err = capsys.readouterr().err.strip()
    assert code != 0 and len(err.splitlines()) == 1 and str(mask) in err and problem in err, err
    assert "Traceback" not in err and "transforms.json: frame" in err  # where it was named


def test_a_corrupt_mask_beside_colmap_images_names_it(dense, tmp_path):
    import shutil

    _, folder = dense
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy, symlinks=True)
    victim = next(p for p in sorted((copy / "masks").iterdir()) if "novel" in p.name)
    victim.write_bytes(b"")
    with pytest.raises(InputError, match="mask file is empty") as e:
        read_scene(copy)
    assert str(e.value).startswith(str(victim))
