"""What the user sees (issue 14, sections 3, 5 and 7), through the CLI on tiny scenes.

Section 3: inputs that belong together must match (plan vs run and scene, resume vs the run's scene).
Section 5: the last tracebacks and cryptic messages, each one line naming the file and the problem.
Section 7: what the user sees when things go right (summaries, progress, repeated messages, info).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from sparself.cli import main
from test_bad_input import listing, make_scene, one_error, run, write_posed

TRAIN = ("--epochs", "1", "--size", "32", "--crop", "16", "--device", "cpu", "--batch-size", "6")


def _colmap_text(folder: Path, n: int = 6) -> Path:
    return write_posed(folder, make_scene(n), "colmap_text")


def _edit_first_image_line(images_txt: Path, field: int, value: str) -> None:
    lines = images_txt.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#"))
    parts = lines[k].split()
    parts[field] = value
    lines[k] = " ".join(parts)
    images_txt.write_text("\n".join(lines) + "\n")


# ---- section 5: remaining tracebacks and cryptic messages ------------------------------------------------------

@pytest.mark.parametrize("cmd", ["info", "plan"])
def test_zero_quaternion_in_images_txt(tmp_path, capsys, cmd):
    scene = _colmap_text(tmp_path / "s")
    _edit_first_image_line(scene / "sparse" / "0" / "images.txt", slice(1, 5), "0 0 0 0")
    argv = ["info", scene] if cmd == "info" else ["plan", scene, "--out", tmp_path / "p.json"]
    code, _, err = run(capsys, *argv)
    one_error(code, err, cmd, "images.txt", "00.png", "quaternion", "is zero", case="zero quaternion [%s]" % cmd)
    assert not (tmp_path / "p.json").exists()


def test_camera_missing_from_cameras_txt(tmp_path, capsys):
    scene = _colmap_text(tmp_path / "s")
    _edit_first_image_line(scene / "sparse" / "0" / "images.txt", 8, "7")
    code, _, err = run(capsys, "info", scene)
    line = one_error(code, err, "info", "images.txt", "camera 7", "cameras.txt", case="camera id missing [info]")
    assert "Rig" not in line and "(it lists 1)" in line


def test_text_file_named_poses_bounds_npy(tmp_path, capsys):
    scene = write_posed(tmp_path / "s", make_scene(6), "llff")
    (scene / "poses_bounds.npy").write_text("0 0 0 1\n")
    code, _, err = run(capsys, "info", scene)
    line = one_error(code, err, "info", "poses_bounds.npy", "not a numpy .npy file", case="text poses_bounds.npy")
    assert "pickle" not in line


def test_llff_count_mismatch_names_the_extra_image(tmp_path, capsys):
    scene = write_posed(tmp_path / "s", make_scene(6), "llff")
    shutil.copy(scene / "images" / "03.png", scene / "images" / "zz.png")
    for k, p in enumerate(sorted((scene / "images").iterdir())):
        t = 2_000_000_000 if p.name == "00.png" else 1_000_000_000 + k  # 00.png: sorted first, added last
        os.utime(p, (t, t))
    code, _, err = run(capsys, "info", scene)
    one_error(code, err, "info", "poses_bounds.npy", "6 poses but 7 images", "extra image 00.png", "newest",
              case="extra image, guessed by age [info]")
    # a COLMAP model beside it (LLFF's imgs2poses leaves one) tells exactly which image has no pose
    write_posed(tmp_path / "c", make_scene(6), "colmap")
    shutil.copytree(tmp_path / "c" / "sparse", scene / "sparse")
    code, _, err = run(capsys, "info", scene / "poses_bounds.npy")
    one_error(code, err, "info", "extra image zz.png", "not in the COLMAP model", case="extra image [info]")


def test_train_size_too_small(tmp_path, capsys):
    scene = write_posed(tmp_path / "s", make_scene(6), "colmap")
    code, _, err = run(capsys, "train", scene, "--out", tmp_path / "run", "--size", "8", "--epochs", "1")
    one_error(code, err, "train", "8 px is too small", "--size", case="train --size 8")
    assert listing(tmp_path) == ["s"]


def test_weights_pointing_at_a_text_file(tmp_path, capsys):
    scene = write_posed(tmp_path / "s", make_scene(6), "colmap")
    txt = tmp_path / "weights.txt"
    txt.write_text("https://download.pytorch.org/models/resnet18-f37072fd.pth\n")
    code, _, err = run(capsys, "train", scene, "--out", tmp_path / "run", "--weights", txt, *TRAIN)
    line = one_error(code, err, "train", "weights.txt", "not a torch weights file", "--weights none",
                     case="--weights text file [train]")
    assert "weights_only" not in err and "documentation" not in line
    assert not (tmp_path / "run").exists()


def test_poses_does_not_claim_to_downscale_small_photos(tmp_path, capsys):
    from PIL import Image

    d = tmp_path / "photos"
    d.mkdir()
    for i in range(3):
        Image.fromarray((np.random.default_rng(i).random((72, 96, 3)) * 255).astype(np.uint8)).save(d / f"{i}.png")
    code, _, err = run(capsys, "poses", d, "--out", tmp_path / "out")
    assert code != 0 and "extracting SIFT features from 3 images" in err
    assert "downscaled" not in err
    code, _, err = run(capsys, "poses", d, "--out", tmp_path / "out", "--max-image-size", "64")
    assert "downscaled from 96 to 64 px" in err
