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


# ---- section 3: inputs that belong together must match ----------------------------------------------------------

def _moved_scene(n: int = 6, dx: float = 0.1) -> "object":
    """make_scene's views with the same names, cameras spaced ``dx`` apart instead of 0.1."""
    from sparself.geometry import Pose

    s = make_scene(n)
    for i, f in enumerate(s.frames):
        f.pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([dx * i, 0.0, 0.0]))
    return s


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """A 6-view scene, trained (1 epoch) from a relative path, and its plan; plus other scenes and plans."""
    root = tmp_path_factory.mktemp("small_run")
    write_posed(root / "scene", make_scene(6), "colmap")
    write_posed(root / "eight", make_scene(8), "colmap")
    write_posed(root / "renamed", make_scene(6, ext=".jpg"), "colmap")
    write_posed(root / "wider", _moved_scene(6, 0.3), "colmap")
    cwd = os.getcwd()
    os.chdir(root)  # the run records its scene from a relative path
    try:
        assert main(["train", "scene", "--out", "run", *TRAIN, "-q"]) == 0
        for name in ("scene", "eight", "renamed", "wider"):
            assert main(["plan", name, "--out", f"plan_{name}.json", "--n-mid", "3", "--n-extra", "1", "-q"]) == 0
    finally:
        os.chdir(cwd)
    return root


def _synth(capsys, root: Path, out: Path, *extra, run_dir=None, plan=None):
    return run(capsys, "synthesize", run_dir or root / "run", "--plan", plan or root / "plan_scene.json",
               "--out", out, "-q", *extra)


def test_run_records_its_scene_absolutely_and_synthesizes_from_elsewhere(small_run, tmp_path, capsys, monkeypatch):
    import torch

    meta = torch.load(small_run / "run" / "checkpoint.pt", weights_only=False)["meta"]
    assert Path(meta["scene"]).is_absolute() and Path(meta["scene"]).exists()
    monkeypatch.chdir(tmp_path)  # another working directory
    code, out, err = _synth(capsys, small_run, tmp_path / "dense")
    assert code == 0, err
    assert (tmp_path / "dense" / "transforms.json").is_file()


@pytest.mark.parametrize("other, needles", [
    ("eight", ("plan_eight.json", "plan was made for 8 views", "this scene has 6")),
    ("renamed", ("plan_renamed.json", "plan was made for other views", "00.jpg")),
    ("wider", ("plan_wider.json", "cameras elsewhere")),
])
def test_plan_made_for_another_scene_is_refused(small_run, tmp_path, capsys, other, needles):
    code, _, err = _synth(capsys, small_run, tmp_path / "dense", plan=small_run / f"plan_{other}.json")
    one_error(code, err, "synthesize", *needles, case=f"plan for another scene ({other}) [synthesize]")
    assert not (tmp_path / "dense").exists()


def _edited_plan(small_run: Path, dst: Path, edit) -> Path:
    doc = json.loads((small_run / "plan_scene.json").read_text())
    edit(doc)
    dst.write_text(json.dumps(doc))
    return dst


def _far_index(doc: dict) -> None:
    for k in ("n_source_views", "source_frames", "source_center", "source_scale"):
        doc.pop(k)  # a hand-written plan records nothing about its scene
    doc["frames"][0]["index"] = 23.5


@pytest.mark.parametrize("case, edit, needles", [
    ("empty", lambda d: d.__setitem__("frames", []), ("the plan has no frames", "--n-mid")),
    ("version", lambda d: d.__setitem__("version", 2), ("plan version 2", "version 1")),
    ("far index", _far_index, ("planned index 23.5", "outside this scene's views 0..5")),
])
def test_plan_version_emptiness_and_index_range(small_run, tmp_path, capsys, case, edit, needles):
    plan = _edited_plan(small_run, tmp_path / "p.json", edit)
    code, _, err = _synth(capsys, small_run, tmp_path / "dense", plan=plan)
    one_error(code, err, "synthesize", "p.json", *needles, case=f"plan {case} [synthesize]")
    assert not (tmp_path / "dense").exists()


def test_plan_of_nothing_is_refused(small_run, tmp_path, capsys):
    code, _, err = run(capsys, "plan", small_run / "scene", "--out", tmp_path / "p.json", "--n-mid", "0",
                       "--n-extra", "0")
    one_error(code, err, "plan", "--n-mid 0", "--n-extra 0", case="empty plan [plan]")
    assert not (tmp_path / "p.json").exists()


def test_synthesize_with_another_scene_is_refused(small_run, tmp_path, capsys):
    code, _, err = _synth(capsys, small_run, tmp_path / "dense", "--scene", small_run / "wider")
    one_error(code, err, "synthesize", "wider", "not the scene the run", "cameras are elsewhere",
              case="--scene of another capture [synthesize]")


def test_moved_scene_says_pass_scene(small_run, tmp_path, capsys):
    run_dir, scene = tmp_path / "run", tmp_path / "scene"
    shutil.copytree(small_run / "run", run_dir)
    shutil.copytree(small_run / "scene", scene)
    import torch

    ck = torch.load(run_dir / "checkpoint.pt", weights_only=False)
    ck["meta"]["scene"] = str(tmp_path / "gone" / "sparse" / "0")  # the scene was moved away
    torch.save(ck, run_dir / "checkpoint.pt")
    code, _, err = _synth(capsys, small_run, tmp_path / "dense", run_dir=run_dir)
    one_error(code, err, "synthesize", "gone", "not there any more", "pass --scene", case="moved scene [synthesize]")
    code, _, err = _synth(capsys, small_run, tmp_path / "dense", "--scene", scene, run_dir=run_dir)
    assert code == 0, err


def test_swapped_synthesize_arguments(small_run, tmp_path, capsys):
    code, _, err = run(capsys, "synthesize", small_run / "plan_scene.json", "--plan", small_run / "run",
                       "--out", tmp_path / "dense")
    one_error(code, err, "synthesize", "plan_scene.json", "arguments are swapped", case="swapped arguments")
    assert not (tmp_path / "dense").exists()


@pytest.mark.parametrize("other, needles", [("eight", ("trained on 6 views", "has 8")),
                                            ("wider", ("cameras are elsewhere",))])
def test_resume_on_another_scene_is_refused(small_run, tmp_path, capsys, other, needles):
    run_dir = tmp_path / "run"
    shutil.copytree(small_run / "run", run_dir)
    before = {p.name: p.read_bytes() for p in run_dir.iterdir()}
    code, _, err = run(capsys, "train", small_run / other, "--out", run_dir, *TRAIN[:1], "2", *TRAIN[2:],
                       "--resume", "-q")
    one_error(code, err, "train", other, "not the scene", "resume with that scene", *needles,
              case=f"--resume on another scene ({other}) [train]")
    assert {p.name: p.read_bytes() for p in run_dir.iterdir()} == before
