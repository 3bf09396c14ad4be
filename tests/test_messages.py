"""What the user sees, through the CLI on tiny scenes.

Inputs that belong together must match (plan vs run and scene, resume vs the run's scene).
The last tracebacks and cryptic messages, each one line naming the file and the problem.
What the user sees when things go right (summaries, progress, repeated messages, info).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from planescene import noise_scene as make_scene
from sparself.cli import main
from test_bad_input import listing, one_error, run, write_posed

TRAIN = ("--epochs", "1", "--size", "32", "--crop", "16", "--device", "cpu", "--batch-size", "6")
# densify trains at the scene's size; --recon none: no self-check fits
DENSIFY = ("--epochs", "1", "--crop", "16", "--device", "cpu", "--batch-size", "6", "--recon", "none")


def _colmap_text(folder: Path, n: int = 6) -> Path:
    return write_posed(folder, make_scene(n), "colmap_text")


def _edit_first_image_line(images_txt: Path, field: int, value: str) -> None:
    lines = images_txt.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#"))
    parts = lines[k].split()
    parts[field] = value
    lines[k] = " ".join(parts)
    images_txt.write_text("\n".join(lines) + "\n")


# ---- remaining tracebacks and cryptic messages ---------------------------------------------------------------


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


@pytest.mark.parametrize(
    "case, pack, needles",
    [
        ("zero quaternion", ("<4d", 12, (0.0, 0.0, 0.0, 0.0)), ("quaternion", "is zero")),
        ("camera id missing", ("<I", 68, (7,)), ("camera 7 is not in", "cameras.bin", "(it lists 1)")),
    ],
)
def test_binary_model_zero_quaternion_and_missing_camera(tmp_path, capsys, case, pack, needles):
    """The same checks in images.bin (image 1's record: id at byte 8, qvec at 12, camera id at 68)."""
    import struct

    scene = write_posed(tmp_path / "s", make_scene(6), "colmap")
    p = scene / "sparse" / "0" / "images.bin"
    data = bytearray(p.read_bytes())
    assert struct.unpack_from("<I4dI", data, 8)[:2] == (1, 1.0) and struct.unpack_from("<I", data, 68) == (1,)
    fmt, off, vals = pack
    struct.pack_into(fmt, data, off, *vals)
    p.write_bytes(bytes(data))
    code, _, err = run(capsys, "info", scene)
    line = one_error(code, err, "info", "images.bin", "image 1 (00.png)", *needles, case=f"{case} (binary) [info]")
    assert "Rig" not in line and "Check failed" not in line


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
    one_error(
        code,
        err,
        "info",
        "poses_bounds.npy",
        "6 poses but 7 images",
        "extra image 00.png",
        "newest",
        case="extra image, guessed by age [info]",
    )
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
    line = one_error(
        code,
        err,
        "train",
        "weights.txt",
        "cannot read as torch weights",
        "not a zip archive or a pickle",
        "--weights none",
        case="--weights text file [train]",
    )
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


# ---- inputs that belong together must match -------------------------------------------------------------------


def _moved_scene(n: int = 6, dx: float = 0.1) -> "object":
    """make_scene's views with the same names, cameras spaced ``dx`` apart instead of 0.1."""
    from sparself.core.geometry import Pose

    s = make_scene(n)
    for i, f in enumerate(s.frames):
        f.pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([dx * i, 0.0, 0.0]))
    return s


@pytest.fixture(scope="module")
def run6(tmp_path_factory):
    """A 6-view scene, trained (1 epoch) from a relative path, and its plan; plus other scenes and plans."""
    root = tmp_path_factory.mktemp("run6")
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
    return run(
        capsys,
        "synthesize",
        run_dir or root / "run",
        "--plan",
        plan or root / "plan_scene.json",
        "--out",
        out,
        "-q",
        *extra,
    )


def test_run_records_its_scene_absolutely_and_synthesizes_from_elsewhere(run6, tmp_path, capsys, monkeypatch):
    import torch

    meta = torch.load(run6 / "run" / "checkpoint.pt", weights_only=False)["meta"]
    assert Path(meta["scene"]).is_absolute() and Path(meta["scene"]).exists()
    monkeypatch.chdir(tmp_path)  # another working directory
    code, out, err = _synth(capsys, run6, tmp_path / "dense")
    assert code == 0, err
    assert (tmp_path / "dense" / "transforms.json").is_file()


@pytest.mark.parametrize(
    "other, needles",
    [
        ("eight", ("plan_eight.json", "plan was made for 8 views", "this scene has 6")),
        ("renamed", ("plan_renamed.json", "plan was made for other views", "00.jpg")),
        ("wider", ("plan_wider.json", "cameras elsewhere")),
    ],
)
def test_plan_made_for_another_scene_is_refused(run6, tmp_path, capsys, other, needles):
    code, _, err = _synth(capsys, run6, tmp_path / "dense", plan=run6 / f"plan_{other}.json")
    one_error(code, err, "synthesize", *needles, case=f"plan for another scene ({other}) [synthesize]")
    assert not (tmp_path / "dense").exists()


def _edited_plan(run6: Path, dst: Path, edit) -> Path:
    doc = json.loads((run6 / "plan_scene.json").read_text())
    edit(doc)
    dst.write_text(json.dumps(doc))
    return dst


def _far_index(doc: dict) -> None:
    for k in ("n_source_views", "source_frames", "source_center", "source_scale"):
        doc.pop(k)  # a hand-written plan records nothing about its scene
    doc["frames"][0]["index"] = 23.5


@pytest.mark.parametrize(
    "case, edit, needles",
    [
        ("empty", lambda d: d.__setitem__("frames", []), ("the plan has no frames", "--n-mid")),
        ("version", lambda d: d.__setitem__("version", 2), ("plan version 2", "version 1")),
        ("far index", _far_index, ("planned index 23.5", "outside this scene's views 0..5")),
    ],
)
def test_plan_version_emptiness_and_index_range(run6, tmp_path, capsys, case, edit, needles):
    plan = _edited_plan(run6, tmp_path / "p.json", edit)
    code, _, err = _synth(capsys, run6, tmp_path / "dense", plan=plan)
    one_error(code, err, "synthesize", "p.json", *needles, case=f"plan {case} [synthesize]")
    assert not (tmp_path / "dense").exists()


def test_plan_of_nothing_is_refused(run6, tmp_path, capsys):
    code, _, err = run(capsys, "plan", run6 / "scene", "--out", tmp_path / "p.json", "--n-mid", "0", "--n-extra", "0")
    one_error(code, err, "plan", "--n-mid 0", "--n-extra 0", case="empty plan [plan]")
    assert not (tmp_path / "p.json").exists()


def test_synthesize_with_another_scene_is_refused(run6, tmp_path, capsys):
    code, _, err = _synth(capsys, run6, tmp_path / "dense", "--scene", run6 / "wider")
    one_error(
        code,
        err,
        "synthesize",
        "wider",
        "not the scene the run",
        "cameras are elsewhere",
        case="--scene of another capture [synthesize]",
    )


def test_moved_scene_says_pass_scene(run6, tmp_path, capsys):
    run_dir, scene = tmp_path / "run", tmp_path / "scene"
    shutil.copytree(run6 / "run", run_dir)
    shutil.copytree(run6 / "scene", scene)
    import torch

    ck = torch.load(run_dir / "checkpoint.pt", weights_only=False)
    ck["meta"]["scene"] = str(tmp_path / "gone" / "sparse" / "0")  # the scene was moved away
    torch.save(ck, run_dir / "checkpoint.pt")
    code, _, err = _synth(capsys, run6, tmp_path / "dense", run_dir=run_dir)
    one_error(code, err, "synthesize", "gone", "not there any more", "pass --scene", case="moved scene [synthesize]")
    code, _, err = _synth(capsys, run6, tmp_path / "dense", "--scene", scene, run_dir=run_dir)
    assert code == 0, err


def test_swapped_synthesize_arguments(run6, tmp_path, capsys):
    code, _, err = run(
        capsys, "synthesize", run6 / "plan_scene.json", "--plan", run6 / "run", "--out", tmp_path / "dense"
    )
    one_error(code, err, "synthesize", "plan_scene.json", "arguments are swapped", case="swapped arguments")
    assert not (tmp_path / "dense").exists()


@pytest.mark.parametrize(
    "other, needles", [("eight", ("trained on 6 views", "has 8")), ("wider", ("cameras are elsewhere",))]
)
def test_resume_on_another_scene_is_refused(run6, tmp_path, capsys, other, needles):
    run_dir = tmp_path / "run"
    shutil.copytree(run6 / "run", run_dir)
    before = {p.name: p.read_bytes() for p in run_dir.iterdir()}
    code, _, err = run(capsys, "train", run6 / other, "--out", run_dir, *TRAIN[:1], "2", *TRAIN[2:], "--resume", "-q")
    one_error(
        code,
        err,
        "train",
        other,
        "not the scene",
        "resume with that scene",
        *needles,
        case=f"--resume on another scene ({other}) [train]",
    )
    assert {p.name: p.read_bytes() for p in run_dir.iterdir()} == before


# ---- what the user sees when things go right ------------------------------------------------------------------

SUMMARY = r" in \d+\.\d s$"


def _one_stdout_line(out: str) -> str:
    lines = out.strip().splitlines()
    assert len(lines) == 1, out
    return lines[0]


def test_every_command_ends_with_a_summary(run6, tmp_path, capsys):
    import re

    code, out, err = run(capsys, "train", run6 / "scene", "--out", tmp_path / "run", *TRAIN, "-q")
    assert code == 0, err
    line = _one_stdout_line(out)
    assert re.match(
        rf"trained 1 epoch on 6 real views -> {re.escape(str(tmp_path / 'run'))} "
        rf"\(checkpoint.pt, config.json, train_log.csv\){SUMMARY}",
        line,
    ), line
    code, out, err = run(
        capsys, "plan", run6 / "scene", "--out", tmp_path / "p.json", "--n-mid", "3", "--n-extra", "1", "-q"
    )
    assert code == 0 and re.match(rf"planned 4 novel poses -> .*p.json{SUMMARY}", _one_stdout_line(out)), out
    code, out, err = _synth(capsys, run6, tmp_path / "dense", plan=tmp_path / "p.json")
    line = _one_stdout_line(out)
    assert code == 0 and re.match(
        rf"wrote 10 views \(6 real \+ 4 synthesized\) -> .*dense \(images/, sparse/0, "
        rf"poses_bounds.npy, transforms.json\){SUMMARY}",
        line,
    ), line
    code, out, err = run(
        capsys, "densify", run6 / "scene", "--out", tmp_path / "d", *DENSIFY, "--n-mid", "2", "--n-extra", "1", "-q"
    )
    line = _one_stdout_line(out)
    assert code == 0 and re.match(
        rf"wrote 9 views \(6 real \+ 3 synthesized\) -> .*d/scene \(run: .*d/run, "
        rf"plan: .*d/plan.json\){SUMMARY}",
        line,
    ), line
    assert "INFO" not in err  # -q: warnings only


class _Terminal:
    """A stand-in for stderr that says it is a terminal."""

    def __init__(self) -> None:
        import io

        self.buf = io.StringIO()

    def isatty(self) -> bool:
        return True

    def write(self, s: str) -> int:
        return self.buf.write(s)

    def flush(self) -> None:
        pass


@pytest.mark.parametrize("tty, quiet, bar", [(True, False, True), (True, True, False), (False, False, False)])
def test_training_bar_only_on_a_terminal_and_never_with_q(run6, tmp_path, capsys, monkeypatch, tty, quiet, bar):
    import sys

    term = _Terminal()
    if tty:
        monkeypatch.setattr(sys, "stderr", term)
    code = main(
        [str(a) for a in ("train", run6 / "scene", "--out", tmp_path / "run", *TRAIN)] + (["-q"] if quiet else [])
    )
    err = term.buf.getvalue() if tty else capsys.readouterr().err
    assert code == 0, err
    assert ("\r" in err) == bar, err
    if bar:
        assert "train:" in err and "1/1" in err
    else:
        assert "\x1b" not in err
    if not quiet:  # before the first checkpoint, whether there is a bar or not
        assert "INFO: train: 6 views at 32x24 px, epochs 1 to 1; a checkpoint every 5 epochs in " in err, err


@pytest.mark.parametrize("tty, quiet, progress", [(True, False, True), (True, True, False), (False, False, False)])
def test_evaluate_bars_only_on_a_terminal_and_never_with_q(tmp_path, monkeypatch, tty, quiet, progress):
    """What evaluate is asked to draw (its work is replaced: the full run is tested below)."""
    import sys

    from sparself.evaluation import evaluate as ev
    from sparself.evaluation.results_file import Results
    from sparself.evaluation.scene_results import SceneResult

    seen = {}

    def fake(paths, out, cfg, overwrite=False, resume=False):
        seen["progress"] = cfg.progress
        return Results(scenes=[SceneResult("x", status="ok")])

    monkeypatch.setattr(ev, "evaluate", fake)
    if tty:
        monkeypatch.setattr(sys, "stderr", _Terminal())
    assert main(["evaluate", str(tmp_path), "--out", str(tmp_path / "o")] + (["-q"] if quiet else [])) == 0
    assert seen["progress"] is progress


def test_evaluate_log_file_lpips_notice_and_report(tmp_path, monkeypatch):
    """A real --quick evaluation with stderr going to a file: no bar fragments or escape codes, the LPIPS
    notice said once, the report's LPIPS tables collapsed into the line that says why."""
    import subprocess
    import sys

    import test_evaluate as te
    from sparself.capture.io import write_scene

    write_scene(te._capture(tmp_path / "cap_images"), tmp_path / "cap", formats=("llff",))
    env = dict(os.environ, TORCH_HOME=str(tmp_path / "torch"), OMP_NUM_THREADS="1")
    env.pop("SPARSELF_LPIPS_DIR", None)
    with open(tmp_path / "log.txt", "w") as log:
        code = subprocess.call(
            [
                sys.executable,
                "-m",
                "sparself.cli",
                "evaluate",
                str(tmp_path / "cap"),
                "--out",
                str(tmp_path / "report"),
                "--quick",
                "--size",
                "32",
                "--inputs",
                "5",
                "--epochs",
                "1",
                "--recon",
                "mpi",
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
        )
    text = (tmp_path / "log.txt").read_text()
    assert code == 0, text
    assert "\r" not in text and "\x1b" not in text and "it/s" not in text, text
    assert text.count("LPIPS unavailable") == 1, text
    assert text.strip().splitlines()[-1].startswith("evaluated 1 scene(s) -> ")
    md = (tmp_path / "report" / "report.md").read_text()
    # without weights no LPIPS column or table is drawn, and why is said once, in the "Not run" list
    assert "| unavailable |" not in md and "LPIPS ↓" not in md
    assert md.count("- LPIPS: unavailable: weights not found") == 1
    page = (tmp_path / "report" / "report.html").read_text()
    assert "<td>unavailable</td>" not in page and page.count("<li>LPIPS: unavailable: weights not found") == 1


def test_ctrl_c_keeps_the_checkpoint_and_prints_the_resume_command(run6, tmp_path, capsys, monkeypatch):
    import shlex

    import sparself.synthesis.train as tr

    real = tr._append_log

    def stop_at_7(path, epoch, *a):
        if epoch == 7:
            raise KeyboardInterrupt
        real(path, epoch, *a)

    monkeypatch.setattr(tr, "_append_log", stop_at_7)
    code, out, err = run(capsys, "train", run6 / "scene", "--out", tmp_path / "run", "--epochs", "8", *TRAIN[2:], "-q")
    assert code == 130 and out == "", err
    lines = [ln for ln in err.splitlines() if ln.startswith("sparself train:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    line = lines[0]
    prefix = "sparself train: interrupted; the checkpoint at epoch 5 is kept in "
    assert line.startswith(prefix + str(tmp_path / "run" / "checkpoint.pt") + "; continue with: sparself train "), line
    command = line.split("; continue with: ")[1]
    assert command.endswith(" --resume") and "--epochs 8" in command
    monkeypatch.setattr(tr, "_append_log", real)
    code, out, err = run(capsys, *shlex.split(command)[1:])  # the command as printed, run as it is
    assert code == 0, err
    assert tr.checkpoint_epoch(tmp_path / "run") == 8
    assert (tmp_path / "run" / "train_log.csv").read_text().count("\n") == 9  # header + epochs 1..8


def test_repeated_per_view_messages_are_said_once_with_a_count(run6, tmp_path, capsys):
    from PIL import Image

    scene = write_posed(tmp_path / "s", make_scene(6), "colmap")
    for name in ("01.png", "02.png", "03.png", "04.png"):
        p = scene / "images" / name
        Image.open(p).convert("L").save(p)
    code, out, err = run(capsys, "train", scene, "--out", tmp_path / "run", *TRAIN)
    assert code == 0, err
    said = [ln for ln in err.splitlines() if "converted to RGB" in ln]
    assert len(said) == 1 and "4 grayscale" in said[0] and "01.png, 02.png, 03.png, 04.png" in said[0], err
    # synthesize reads the scene's depth bounds more than once: the warning is said once
    code, out, err = run(
        capsys, "synthesize", run6 / "run", "--plan", run6 / "plan_scene.json", "--out", tmp_path / "dense"
    )
    assert code == 0, err
    assert err.count("guessing near/far from camera layout") == 1, err


def test_messages_about_many_files_are_collected():
    """The CLI's filter: the same message again is dropped; '<file>: <what>' for other files is counted
    and said once at the end, naming them."""
    import logging

    from sparself.core.logs import Repeats as _Repeats

    rep = _Repeats()

    def rec(msg, *args):
        return logging.LogRecord("sparself.x", logging.WARNING, __file__, 1, msg, args, None)

    shown = [r.getMessage() for r in (rec("%s: distortion dropped", f"{i:02d}.png") for i in range(8)) if rep.filter(r)]
    shown += [
        r.getMessage()
        for r in (
            rec("no bounds; guessing"),
            rec("no bounds; guessing"),
            rec("%s: %s image converted", "a.png", "RGBA"),
        )
        if rep.filter(r)
    ]
    assert shown == ["00.png: distortion dropped", "no bounds; guessing", "a.png: RGBA image converted"]
    assert [r.getMessage() for r in rep.rest()] == [
        "01.png, 02.png, 03.png, 04.png, 05.png and 2 more: distortion dropped"
    ]


def test_llff_focal_scaling_said_once(tmp_path, capsys):
    scene = write_posed(tmp_path / "s", make_scene(6), "llff")
    arr = np.load(scene / "poses_bounds.npy")
    arr[:, 4], arr[:, 9], arr[:, 14] = 48, 64, arr[:, 14] * 2  # poses for images twice the size
    np.save(scene / "poses_bounds.npy", arr)
    code, out, err = run(capsys, "info", scene)
    assert code == 0, err
    said = [ln for ln in err.splitlines() if "scaling focal" in ln]
    assert said == ["INFO: poses_bounds.npy: 6 of 6 images are 32x24, poses say 64x48; scaling focal by 0.5000"]


def test_info_separates_real_and_synthesized_views_and_says_where_bounds_come_from(run6, tmp_path, capsys):
    code, out, err = _synth(capsys, run6, tmp_path / "dense")
    assert code == 0, err
    code, out, err = run(capsys, "info", tmp_path / "dense")
    assert "views:         10 (6 real + 4 synthesized)" in out
    assert "from a guess from the camera layout" in out and "no stored bounds" in out
    code, out, err = run(capsys, "info", tmp_path / "dense", "--json")
    info = json.loads(out)
    assert (info["views"], info["real_views"], info["synthesized_views"]) == (10, 6, 4)
    llff = write_posed(tmp_path / "llff", make_scene(6), "llff")
    code, out, err = run(capsys, "info", llff)
    assert "views:         6 (6 real + 0 synthesized)" in out
    assert "depth bounds:  near 1, far 5, from the near/far bounds stored in poses_bounds.npy" in out


def test_ctrl_c_in_densify_says_nothing_was_written(run6, tmp_path, capsys, monkeypatch):
    import sparself.synthesis.train as tr

    def stop(*a):
        raise KeyboardInterrupt

    monkeypatch.setattr(tr, "_append_log", stop)
    code, out, err = run(capsys, "densify", run6 / "scene", "--out", tmp_path / "d", *DENSIFY, "-q")
    assert code == 130 and out == "", err
    lines = [ln for ln in err.splitlines() if ln.startswith("sparself densify:")]
    assert lines == [f"sparself densify: interrupted; nothing was written to {tmp_path / 'd'}; run the command again"]
    assert listing(tmp_path) == []  # no output, no hidden temporary folder


def test_output_cut_off_by_a_closed_pipe_is_no_traceback(tmp_path):
    """``sparself info SCENE | true``: the reader exits before sparself writes; no BrokenPipeError traceback."""
    import subprocess
    import sys

    scene = _colmap_text(tmp_path / "s")
    cmd = f"'{sys.executable}' -m sparself.cli info '{scene}' | true; echo \"status ${{PIPESTATUS[0]}}\" >&2"
    proc = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=120)
    assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] in ("status 141", "status 0"), proc.stderr


def test_batch_densify_names_each_missing_capture_plainly(tmp_path, capsys):
    """A densify unit is one capture: its failure names the capture, with no seed, each path once."""
    missing = [tmp_path / f"nope{i}" for i in range(1, 5)]
    (tmp_path / "m.txt").write_text("".join(f"{p}\n" for p in missing))
    code, _, err = run(capsys, "batch", "densify", tmp_path / "m.txt", "--out", tmp_path / "b", "--local", "-q")
    assert code == 1
    failed = [ln for ln in err.splitlines() if ln.startswith("  failed: ")]
    assert failed == [f"  failed: {p.name}: {p}: no such folder" for p in missing], err
    assert "seed" not in err and "more)" not in err
