"""Bad input through the CLI, for every command that reads images, poses or runs.

Every failing case checks the same contract: a non-zero exit, exactly one line
``sparself <cmd>: error: ...`` that names the file and the problem, no traceback (without ``--debug``),
and nothing left beside the output (no partial result, no hidden ``.tmp-`` folder).

Policies these tests pin down:

* Mixed image sizes: ``sparself poses`` refuses them (one shared COLMAP camera; the message lists the odd
  files and their sizes). A posed scene carries one camera per size, so the commands that read one
  (``info``, ``plan``, ``train``) accept it, and training resizes every view to ``--size``.
* Grayscale, RGBA and 16-bit PNGs are converted to RGB by ``sparself.capture.scene.load_image`` with a warning
  naming the file; COLMAP reads them as they are (SIFT works on gray anyway).
* EXIF orientation is applied everywhere: COLMAP gets upright copies, every loader applies it.
* ``info`` and ``plan`` read image headers only, so a truncated JPEG is found by the commands that decode
  pixels (``poses``, ``train``, ``evaluate``); an empty or non-image file is found by all of them.

Set ``SPARSELF_RECORD_MESSAGES=FILE`` to collect every error line the user sees (for the issue's note).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from planescene import NF, NH, NW, noise, noise_scene
from sparself.capture.images import load_image, save_image
from sparself.capture.io import read_scene, write_scene
from sparself.capture.io.colmap import write_colmap
from sparself.capture.io.middlebury import write_middlebury
from sparself.capture.scene import Camera, Frame, Scene
from sparself.cli import build_parser, main
from sparself.core.geometry import Pose, rotmat_to_quat, slerp

W, H, F = NW, NH, NF


# ---- helpers ------------------------------------------------------------------------------------------


def _available() -> set[str]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return set(sub.choices)


AVAILABLE = _available()


def need(*cmds: str) -> None:
    """Every command these tests exercise exists: a removed command fails its tests (never skips them)."""
    missing = [c for c in cmds if c not in AVAILABLE]
    assert not missing, f"`sparself {missing[0]}` is missing from the CLI"


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _record(case: str, line: str) -> None:
    dest = os.environ.get("SPARSELF_RECORD_MESSAGES")
    if dest:
        with open(dest, "a") as f:
            f.write(f"{case}\t{line}\n")


def one_error(code: int, err: str, cmd: str, *needles: str, case: str = "") -> str:
    """The contract: non-zero exit, no traceback, one ``sparself <cmd>: error:`` line holding ``needles``."""
    assert code != 0, err
    assert "Traceback" not in err and "Check failure" not in err, err
    lines = [ln for ln in err.splitlines() if ln.startswith(f"sparself {cmd}: error: ")]
    assert len(lines) == 1, err
    for n in needles:
        assert n in lines[0], (n, lines[0])
    _record(case or cmd, lines[0])
    return lines[0]


def listing(folder: Path) -> list[str]:
    """Every entry of a folder, hidden ones (``.x.tmp-...``) included."""
    return sorted(p.name for p in Path(folder).iterdir()) if Path(folder).exists() else []


def texture(h: int, w: int, seed: int) -> np.ndarray:
    return noise(h, w, seed)


make_scene = noise_scene  # the suite's one scene builder (planescene.camera_line), random pixels


def write_posed(folder: Path, scene: Scene, fmt: str = "colmap") -> Path:
    """Write a scene in ONE pose format (so read_scene's autodetection picks that format)."""
    folder = Path(folder)
    if fmt == "middlebury":
        folder.mkdir(parents=True)
        for f in scene.frames:
            save_image(folder / f.name, f.image)
        write_middlebury(scene, folder / "scene_par.txt")
        return folder
    write_scene(scene, folder)
    drop = {
        "colmap": ["poses_bounds.npy", "transforms.json", "sparse_pc.ply"],
        "colmap_text": ["poses_bounds.npy", "transforms.json", "sparse_pc.ply"],
        "llff": ["sparse", "transforms.json", "sparse_pc.ply"],
        "nerfstudio": ["sparse", "poses_bounds.npy", "sparse_pc.ply"],
    }[fmt]
    for name in drop:
        p = folder / name
        shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
    if fmt == "colmap_text":
        model = folder / "sparse" / "0"
        write_colmap(read_scene(folder), model, text=True)
        for p in model.glob("*.bin"):
            p.unlink()
    return folder


def write_photos(folder: Path, n: int, size=(W, H), ext: str = ".png", seed: int = 0) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i in range(n):
        p = folder / f"{i:02d}{ext}"
        save_image(p, texture(size[1], size[0], seed + i))
        out.append(p)
    return out


def truncated_jpeg(path: Path) -> None:
    save_image(path.with_suffix(".jpg"), texture(H, W, 99))
    data = path.with_suffix(".jpg").read_bytes()
    path.with_suffix(".jpg").unlink()
    path.write_bytes(data[: len(data) // 2])


BROKEN = {  # name of the case -> (how to break a file, what the message must say)
    "truncated_jpeg": (truncated_jpeg, "truncated"),
    "zero_byte": (lambda p: p.write_bytes(b""), "empty (0 bytes)"),
    "text_as_jpg": (lambda p: p.write_text("this is not a photo\n"), "not an image"),
}


# ---- commands and their arguments ------------------------------------------------------------------


def argv_for(cmd: str, inp: Path, out: Path, *extra) -> list:
    """The arguments that run ``cmd`` on input ``inp`` with output ``out`` as quickly as possible."""
    if cmd == "info":
        return ["info", inp, *extra]
    if cmd == "plan":
        return ["plan", inp, "--out", out, *extra]
    if cmd == "poses":
        return ["poses", inp, "--out", out, *extra]
    if cmd == "evaluate":
        return ["evaluate", inp, "--out", out, "--quick", "--recon", "mpi", *extra]
    if cmd == "train":
        return ["train", inp, "--out", out, "--epochs", "1", "--size", "32", "--device", "cpu", *extra]
    if cmd == "densify":
        return [
            "densify",
            inp,
            "--out",
            out,
            "--epochs",
            "1",
            "--device",
            "cpu",
            "--recon",
            "none",
            *extra,
        ]  # trains at the photos' size
    raise KeyError(cmd)


SCENE_COMMANDS = ["info", "plan", "evaluate", "train"]  # read a posed scene
PHOTO_COMMANDS = ["poses", "densify"]  # read a folder of photos
WRITING = ["plan", "poses", "evaluate", "train", "densify"]  # write an output


def check_failure(capsys, tmp_path: Path, cmd: str, inp: Path, *needles: str, case: str = "") -> str:
    """Run ``cmd`` on ``inp`` into ``tmp_path/res/out``; assert the contract and that res/ stays empty."""
    need(cmd)
    res = tmp_path / "res"
    res.mkdir(parents=True, exist_ok=True)
    out = res / ("plan.json" if cmd == "plan" else "out")
    before = listing(res)
    code, stdout, err = run(capsys, *argv_for(cmd, inp, out, "-q"))
    if cmd == "evaluate":
        # evaluate reports a failed scene in its report and goes on with the others; with no
        # scene left it exits non-zero and the logged error names the file and the problem
        assert code != 0 and "Traceback" not in err, err
        lines = [ln for ln in err.splitlines() if "evaluation failed" in ln]
        assert len(lines) == 1 and all(n in lines[0] for n in needles), err
        _record(case or cmd, lines[0])
        # what it leaves is a complete report of the failure, not a partial one
        results = json.loads((out / "results.json").read_text())
        assert [s["status"] for s in results["scenes"]] == ["failed"]
        assert listing(res) == sorted(before + ["out"])
        return lines[0]
    line = one_error(code, err, cmd, *needles, case=case)
    assert listing(res) == before, f"{cmd} left {listing(res)}"
    return line


# ---- empty folder, one image, two images ----------------------------------------------------------------


@pytest.mark.parametrize("cmd", SCENE_COMMANDS + PHOTO_COMMANDS)
def test_empty_folder(tmp_path, capsys, cmd):
    (tmp_path / "empty").mkdir()
    needle = "no images found" if cmd in PHOTO_COMMANDS else "no scene found"
    check_failure(capsys, tmp_path, cmd, tmp_path / "empty", "empty", needle, case=f"empty folder [{cmd}]")


@pytest.mark.parametrize("n", [1, 2])
@pytest.mark.parametrize("cmd", PHOTO_COMMANDS)
def test_one_or_two_photos(tmp_path, capsys, cmd, n):
    write_photos(tmp_path / "photos", n)
    check_failure(
        capsys,
        tmp_path,
        cmd,
        tmp_path / "photos",
        "photos",
        f"{n} image(s) found",
        "at least 3",
        case=f"{n} photo(s) [{cmd}]",
    )


@pytest.mark.parametrize("n", [1, 2])
@pytest.mark.parametrize("cmd", ["plan", "train"])
def test_one_or_two_posed_views(tmp_path, capsys, cmd, n):
    scene = write_posed(tmp_path / "scene", make_scene(n), "llff")
    check_failure(capsys, tmp_path, cmd, scene, "at least 3", case=f"{n} posed view(s) [{cmd}]")


def test_info_describes_a_single_view(tmp_path, capsys):
    """Describing one view is not an error: info says what there is."""
    scene = write_posed(tmp_path / "scene", make_scene(1), "llff")
    code, out, err = run(capsys, "info", scene)
    assert code == 0 and "views:         1" in out, err


# ---- broken image files ---------------------------------------------------------------------------------


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_photo(tmp_path, capsys, case):
    """poses (and densify) decode every photo before COLMAP runs and name each broken one."""
    need(*PHOTO_COMMANDS)
    for cmd in PHOTO_COMMANDS:
        d = tmp_path / cmd / "photos"
        write_photos(d, 4)
        BROKEN[case][0](d / "02.jpg")
        check_failure(capsys, tmp_path / cmd, cmd, d, "02.jpg", BROKEN[case][1], case=f"{case} photo [{cmd}]")


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_image_in_a_posed_scene(tmp_path, capsys, case):
    """Commands that decode pixels name the broken file; info/plan read headers only, so they name
    files that are empty or not images and still work on a truncated JPEG."""
    src = make_scene(6, ext=".jpg")
    need(*SCENE_COMMANDS)
    for cmd in SCENE_COMMANDS:
        scene = write_posed(tmp_path / cmd / "scene", src, "llff")
        # frame 0: an input of every command (evaluate holds out interior frames only, and opens those
        # only when it scores them, after all the work)
        BROKEN[case][0](scene / "images" / "00.jpg")
        if case == "truncated_jpeg" and cmd in ("info", "plan"):
            code, _, err = run(capsys, *argv_for(cmd, scene, tmp_path / cmd / "plan.json", "-q"))
            assert code == 0, err
            continue
        check_failure(capsys, tmp_path / cmd, cmd, scene, "00.jpg", BROKEN[case][1], case=f"{case} in scene [{cmd}]")


# ---- mixed sizes, grayscale / RGBA / 16-bit, EXIF ------------------------------------------------------------


def test_mixed_photo_sizes_are_refused_by_poses(tmp_path, capsys):
    d = tmp_path / "photos"
    write_photos(d, 4)
    save_image(d / "09.png", texture(H, W // 2, 9))
    check_failure(
        capsys,
        tmp_path,
        "poses",
        d,
        "different sizes",
        f"{W}x{H}",
        f"09.png ({W // 2}x{H})",
        case="mixed sizes [poses]",
    )


def test_converted_images_warn_and_load_as_rgb(tmp_path, caplog):
    rgb = (texture(H, W, 3) * 255).astype(np.uint8)
    Image.fromarray(rgb).convert("L").save(tmp_path / "gray.png")
    Image.fromarray(rgb).convert("RGBA").save(tmp_path / "rgba.png")
    Image.fromarray((rgb[..., 0].astype(np.uint16) * 257)).save(tmp_path / "deep.png")
    with caplog.at_level("WARNING", logger="sparself"):
        for name in ("gray.png", "rgba.png", "deep.png"):
            img = load_image(tmp_path / name)
            assert img.shape == (H, W, 3) and img.dtype == np.float32
    warned = " ".join(r.getMessage() for r in caplog.records)
    assert all(n in warned for n in ("gray.png", "rgba.png", "deep.png")) and "converted to RGB" in warned
    np.testing.assert_allclose(load_image(tmp_path / "deep.png")[..., 1], rgb[..., 0] / 255.0, atol=1e-6)


def test_exif_rotated_view_of_a_posed_scene_loads_upright(tmp_path, capsys):
    """A view stored sideways with EXIF orientation 6 is the same picture as the upright one for every
    reader (the camera size it is checked against is the upright one)."""
    scene = write_posed(tmp_path / "scene", make_scene(4), "llff")
    p = scene / "images" / "02.png"
    upright = np.asarray(Image.open(p).convert("RGB"))
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 degrees clockwise to display"
    Image.fromarray(upright).transpose(Image.Transpose.ROTATE_90).save(p, exif=exif)
    s = read_scene(scene)
    assert s.image_size(2) == (W, H)
    np.testing.assert_array_equal(np.round(s.load(2) * 255).astype(np.uint8), upright)
    code, out, err = run(capsys, "info", scene)
    assert code == 0 and f"{W}x{H}" in out, err


# ---- poses: one real registration with converted, rotated and unregistrable photos ------------------------


def _look_at(c: np.ndarray, target: np.ndarray) -> Pose:
    z = (target - c) / np.linalg.norm(target - c)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return Pose(rotmat_to_quat(R), -R @ c)


def render_corner(pose: Pose, w: int = 96, h: int = 72, f: float = 80.0) -> np.ndarray:
    """Ray-cast the inside of a box corner (back wall z=2, left wall x=-1.5, floor y=1.2), each wall with
    its own blurred-noise texture: real 3D structure and plenty of SIFT features at 96x72 px."""
    import cv2

    rng = np.random.default_rng(0)
    texs = [cv2.GaussianBlur(rng.random((256, 256, 3)).astype(np.float32), (0, 0), 1.5) for _ in range(3)]
    v, u = np.mgrid[0:h, 0:w] + 0.5
    rays = np.stack([(u - w / 2) / f, (v - h / 2) / f, np.ones_like(u)], -1) @ pose.R
    c = pose.center
    best, img = np.full(u.shape, np.inf), np.zeros(u.shape + (3,), np.float32)
    for tex, (axis, val) in zip(texs, [(2, 2.0), (0, -1.5), (1, 1.2)]):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (val - c[axis]) / rays[..., axis]
        s = np.where(np.isfinite(s) & (s > 0), s, np.inf)
        p = c + np.where(np.isfinite(s), s, 0.0)[..., None] * rays
        a, b = [i for i in range(3) if i != axis]
        col = cv2.remap(
            (tex - tex.min()) / (tex.max() - tex.min()),
            ((p[..., a] * 40) % 256).astype(np.float32),
            ((p[..., b] * 40) % 256).astype(np.float32),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_WRAP,
        )
        m = s < best
        best[m], img[m] = s[m], col[m]
    return img


def test_poses_registers_converted_and_rotated_photos_and_names_the_unregistrable(tmp_path, capsys, monkeypatch):
    """The one real COLMAP run here (about 2 s): 8 views of a textured box corner, saved as RGB, gray,
    RGBA, 16-bit gray and an EXIF-rotated PNG, plus a photo of noise that cannot be registered.
    The noise photo is named and excluded, the run goes on with the other 8, and the rotated one gets
    a pose next to its neighbours (COLMAP saw it upright, as every other stage does)."""
    d = tmp_path / "photos"
    d.mkdir()
    for i in range(8):
        a = -0.25 + 0.5 * i / 7
        c = np.array([np.sin(a) - 0.3, 0.2 * np.cos(3 * a), -2 + 0.3 * np.cos(a)])
        rgb = (np.clip(render_corner(_look_at(c, np.array([-0.3, 0.3, 1.5]))), 0, 1) * 255).astype(np.uint8)
        im = Image.fromarray(rgb)
        if i == 2:
            im.convert("L").save(d / f"{i:02d}.png")
        elif i == 3:
            im.convert("RGBA").save(d / f"{i:02d}.png")
        elif i == 4:
            Image.fromarray(np.asarray(im.convert("L")).astype(np.uint16) * 257).save(d / f"{i:02d}.png")
        elif i == 5:
            exif = Image.Exif()
            exif[0x0112] = 6
            im.transpose(Image.Transpose.ROTATE_90).save(d / f"{i:02d}.png", exif=exif)
        else:
            im.save(d / f"{i:02d}.png")
    noise = np.random.default_rng(5).random((72, 96, 3))
    Image.fromarray((noise * 255).astype(np.uint8)).save(d / "zz_noise.png")
    hashes = {p.name: p.read_bytes() for p in d.iterdir()}
    # the pose check's repair, on this same run: the check calls 03.png a suspect on the first model and on
    # the first repair (so that repair is not taken); the second repair is checked for real
    import sparself.capture.sfm as sfm
    from sparself.capture.posecheck import Suspect

    real_check, calls = sfm.check_poses, []

    def check(scene, stats=None):
        c = real_check(scene, stats)
        calls.append(c.names)
        if len(calls) <= 2:
            c.suspects = [Suspect("03.png", ["flagged by the test"])]
        return c

    monkeypatch.setattr(sfm, "check_poses", check)
    # and photos whose EXIF says a 3x longer lens than these views were rendered with (f = 80 px)
    monkeypatch.setattr(sfm, "exif_focal_px", lambda paths, w, h: 240.0)
    os.chmod(d, 0o555)  # the input folder is only read
    try:
        code, out, err = run(capsys, "poses", d, "--out", tmp_path / "scene", "-q")
    finally:
        os.chmod(d, 0o755)
    assert code == 0, err
    assert "registered 8 of 9 images; not registered: zz_noise.png" in out
    assert "WARNING: sfm: registered 8 of 9 images; not registered: zz_noise.png" in err  # seen with -q too
    assert {p.name: p.read_bytes() for p in d.iterdir()} == hashes
    rep = json.loads((tmp_path / "scene" / "sfm_report.json").read_text())
    assert rep["unregistered"] == ["zz_noise.png"]
    # the real check finds no suspect in any of the three models. Repair 1 (03.png's matches restricted to
    # its neighbours) still "has" the suspect; repair 2 (every photo matched only with its neighbours)
    # registers too few of these wide-baseline views to be taken: the first model is kept, and the summary
    # and the report say plainly that the repair failed
    assert calls == [[], [], []], rep["repair"]
    assert rep["suspects"] == [{"name": "03.png", "reasons": ["flagged by the test"]}]
    assert (
        "1 suspect photo(s), poses probably wrong: 03.png (flagged by the test) [tried matches of the "
        "suspects restricted to their capture-order neighbours (1 pairs dropped): 8 registered, 1 suspect(s); "
        "all matches restricted to capture-order neighbours (a sequential order prior)" in out
    )
    assert rep["repair"].endswith(
        "could not repair: 03.png still look wrong; check or remove these photos (or add "
        "photos between them and their neighbours) and run again"
    )
    assert len(rep["registered"]) == 8
    (cam_line,) = rep["camera"]
    assert (
        "is far from the photos' EXIF focal length 240 px (22.6 deg)" in cam_line and f"WARNING: sfm: {cam_line}" in err
    )
    # conversions said once per kind with a count, and images/ holds upright 8-bit RGB copies
    for what in (
        "1 grayscale L image(s) converted to RGB: 02.png",
        "1 RGBA image(s) converted to RGB (alpha dropped): 03.png",
        "1 16-bit image(s) converted to RGB: 04.png",
    ):
        assert err.count(what) == 1, err
    for i in range(8):
        with Image.open(tmp_path / "scene" / "images" / f"{i:02d}.png") as im:
            assert im.mode == "RGB" and im.size == (96, 72) and im.getexif().get(0x0112, 1) == 1
    assert listing(tmp_path) == ["photos", "scene"]
    scene = read_scene(tmp_path / "scene")
    assert [f.name for f in scene.frames] == [f"{i:02d}.png" for i in range(8)]
    assert scene.image_size(5) == (96, 72) and scene.load(5).shape == (72, 96, 3)
    # the rotated view's pose: between its neighbours, no 90-degree roll
    from sparself.core.geometry import rotation_angle_deg

    R = [f.pose.R for f in scene.frames]
    for i in (4, 6):
        assert rotation_angle_deg(R[5], R[i]) < 10.0
    c = scene.centers()
    assert np.linalg.norm(c[5] - (c[4] + c[6]) / 2) < 0.5 * np.linalg.norm(c[6] - c[4])


def test_too_few_registered_is_a_clear_error(tmp_path, capsys):
    """Photos of noise: COLMAP registers none; one line, no COLMAP log noise, nothing written."""
    d = tmp_path / "photos"
    d.mkdir()
    for i in range(3):
        Image.fromarray((np.random.default_rng(i).random((72, 96, 3)) * 255).astype(np.uint8)).save(d / f"{i}.png")
    line = check_failure(capsys, tmp_path, "poses", d, "photos", "could not register", case="unregistrable [poses]")
    assert "need" in line or "overlap" in line


# ---- identical consecutive poses, 500 views ------------------------------------------------------------------


def test_slerp_of_identical_rotations_is_finite():
    q = np.array([0.9, 0.1, -0.3, 0.2])
    q /= np.linalg.norm(q)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for t in (0.0, 0.5, 1.2):
            np.testing.assert_allclose(slerp(q, q, t), q, atol=1e-12)
            np.testing.assert_allclose(np.abs(slerp(q, -q, t) @ q), 1.0, atol=1e-12)


@pytest.mark.filterwarnings("error")
def test_plan_with_identical_consecutive_poses(tmp_path, capsys):
    scene = write_posed(tmp_path / "scene", make_scene(8, same=(3, 4)), "llff")  # frames 2, 3, 4 coincide
    code, out, err = run(capsys, "plan", scene, "--out", tmp_path / "plan.json", "--n-mid", "7", "--n-extra", "2")
    assert code == 0, err
    assert "02.png and 03.png have the same pose" in err  # the repeated view is pointed out
    frames = json.loads((tmp_path / "plan.json").read_text())["frames"]
    assert len(frames) == 9
    centers = np.array([f["center"] for f in frames])
    assert np.all(np.isfinite(centers)) and np.all(np.isfinite([f["qvec"] for f in frames]))
    np.testing.assert_allclose(np.linalg.norm([f["qvec"] for f in frames], axis=1), 1.0, atol=1e-9)
    # midpoints lie on the camera line between their neighbours; extrapolations past the ends
    xs = sorted(c[0] for c in centers)
    assert xs[0] < 0 and xs[-1] > 0.7 and np.allclose(centers[:, 1:], 0.0, atol=1e-12)


def test_500_views_plan_fast_with_linear_memory(tmp_path, capsys):
    """500 shuffled views on an arc: auto order builds the nearest-neighbour path; the CLI plans in
    seconds and the planner's memory stays far below one N x N matrix (2 MB of float64)."""
    from sparself.synthesis.plan import PlanConfig, plan_poses

    n = 500
    ang = np.random.default_rng(0).permutation(np.linspace(0, np.radians(300), n))
    cam = Camera.pinhole(8, 6, 7.0)
    frames = []
    for k, a in enumerate(ang):
        c = 3.0 * np.array([np.cos(a), 0.0, np.sin(a)])
        frames.append(
            Frame(f"{k:03d}.png", _look_at(c, np.zeros(3)), 1, float(k), None, np.full((6, 8, 3), 0.5, np.float32))
        )
    scene = Scene({1: cam}, frames, bounds=(1.0, 6.0))
    folder = write_posed(tmp_path / "scene", scene, "llff")
    t0 = time.perf_counter()
    code, out, err = run(capsys, "plan", folder, "--out", tmp_path / "plan.json")
    wall = time.perf_counter() - t0
    assert code == 0 and "planned 10 novel poses" in out, err
    assert wall < 30.0, f"plan on 500 views took {wall:.1f} s"  # measured ~1 s; generous for a busy machine
    code, out, err = run(capsys, "info", folder)
    assert code == 0 and "views:         500" in out, err
    tracemalloc.start()
    plan_poses(scene, PlanConfig(order="nearest"))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 1_000_000, f"planning 500 views peaked at {peak / 1e6:.1f} MB"


# ---- pose files: NaN / inf / wrong shape, in every format -----------------------------------------------------


def _edit_llff(folder: Path, how: str) -> None:
    pb = np.load(folder / "poses_bounds.npy")
    if how == "nan":
        pb[2, 3] = np.nan
    elif how == "inf":
        pb[1, 7] = np.inf
    else:
        pb = pb[:, :15]
    np.save(folder / "poses_bounds.npy", pb)


def _edit_transforms(folder: Path, how: str) -> None:
    js = folder / "transforms.json"
    doc = json.loads(js.read_text())
    m = doc["frames"][2]["transform_matrix"]
    if how == "nan":
        m[0][3] = float("nan")
    else:
        doc["frames"][2]["transform_matrix"] = [row[:3] for row in m[:3]]
    js.write_text(json.dumps(doc))  # json writes NaN as the literal NaN, which readers accept


def _edit_colmap_text(folder: Path, how: str) -> None:
    p = folder / "sparse" / "0" / "images.txt"
    lines = p.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#"))
    parts = lines[k].split()
    if how == "nan":
        parts[5] = "nan"
    else:
        del parts[5]
    lines[k] = " ".join(parts)
    p.write_text("\n".join(lines) + "\n")


def _edit_middlebury(folder: Path, how: str) -> None:
    p = folder / "scene_par.txt"
    lines = p.read_text().splitlines()
    parts = lines[3].split()
    if how == "inf":
        parts[-1] = "inf"
    else:
        del parts[-1]
    lines[3] = " ".join(parts)
    p.write_text("\n".join(lines) + "\n")


POSE_FILES = {  # case -> (format, edit, how, words the message must hold)
    "llff_nan": ("llff", _edit_llff, "nan", ("poses_bounds.npy", "NaN or inf")),
    "llff_inf": ("llff", _edit_llff, "inf", ("poses_bounds.npy", "NaN or inf")),
    "llff_shape": ("llff", _edit_llff, "shape", ("poses_bounds.npy", "(N, 17)", "(6, 15)")),
    "transforms_nan": ("nerfstudio", _edit_transforms, "nan", ("transforms.json", "frame 2", "NaN or inf")),
    "transforms_shape": ("nerfstudio", _edit_transforms, "shape", ("transforms.json", "frame 2", "4x4", "(3, 3)")),
    "colmap_nan": ("colmap_text", _edit_colmap_text, "nan", ("sparse/0/images.txt", "line 5", "NaN or inf")),
    "colmap_shape": (
        "colmap_text",
        _edit_colmap_text,
        "shape",
        ("sparse/0/images.txt", "line 5 has 9 fields", "expected IMAGE_ID QW QX QY QZ TX TY TZ"),
    ),
    "middlebury_inf": ("middlebury", _edit_middlebury, "inf", ("scene_par.txt", "line 4", "NaN or inf")),
    "middlebury_shape": ("middlebury", _edit_middlebury, "shape", ("scene_par.txt", "line 4", "21 fields")),
}


@pytest.mark.parametrize("case", sorted(POSE_FILES))
def test_bad_pose_file(tmp_path, capsys, case):
    fmt, edit, how, needles = POSE_FILES[case]
    original = write_posed(tmp_path / "orig", make_scene(6), fmt)
    edit(original, how)
    hashes = {p: p.read_bytes() for p in original.rglob("*") if p.is_file()}
    need(*SCENE_COMMANDS, "densify")
    for cmd in SCENE_COMMANDS + ["densify"]:  # densify reads a posed scene too (and must not fall back to SfM)
        check_failure(capsys, tmp_path / cmd, cmd, original, *needles, case=f"{case} [{cmd}]")
    assert {p: p.read_bytes() for p in original.rglob("*") if p.is_file()} == hashes  # inputs untouched


# ---- output folders: existing, unwritable ------------------------------------------------------------------


@pytest.mark.parametrize("cmd", WRITING)
def test_existing_non_empty_output_is_refused(tmp_path, capsys, cmd):
    need(cmd)
    inp = (
        write_photos(tmp_path / "photos", 3)[0].parent
        if cmd in PHOTO_COMMANDS
        else write_posed(tmp_path / "scene", make_scene(6), "llff")
    )
    out = tmp_path / ("plan.json" if cmd == "plan" else "out")
    if cmd == "plan":
        out.write_text("keep me")
    else:
        out.mkdir()
        (out / "old.txt").write_text("keep me")
    before = listing(tmp_path)
    code, _, err = run(capsys, *argv_for(cmd, inp, out, "-q"))
    one_error(code, err, cmd, str(out), "--overwrite", case=f"existing output [{cmd}]")
    assert listing(tmp_path) == before
    assert (out if cmd == "plan" else out / "old.txt").read_text() == "keep me"
    assert "sfm:" not in err  # refused before any work


def test_overwrite_replaces_an_existing_output(tmp_path, capsys):
    scene = write_posed(tmp_path / "scene", make_scene(6), "llff")
    assert run(capsys, "plan", scene, "--out", tmp_path / "plan.json", "--n-mid", "1", "-q")[0] == 0  # an old plan
    code, _, err = run(capsys, "plan", scene, "--out", tmp_path / "plan.json", "--overwrite", "-q")
    assert code == 0, err
    assert json.loads((tmp_path / "plan.json").read_text())["format"] == "sparself-plan"
    assert len(json.loads((tmp_path / "plan.json").read_text())["frames"]) > 3  # the new plan, not the old
    assert listing(tmp_path) == ["plan.json", "scene"]


@pytest.mark.parametrize("cmd", WRITING)
def test_unwritable_output_is_refused_before_any_work(tmp_path, capsys, cmd):
    """An output under a regular file, and one on a read-only file system (/proc: refused even to root)."""
    need(cmd)
    inp = (
        write_photos(tmp_path / "photos", 3)[0].parent
        if cmd in PHOTO_COMMANDS
        else write_posed(tmp_path / "scene", make_scene(6), "llff")
    )
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    before = listing(tmp_path)
    for out in (
        blocker / ("plan.json" if cmd == "plan" else "out"),
        Path("/proc") / ("sparself_plan.json" if cmd == "plan" else "sparself_out"),
    ):
        t0 = time.perf_counter()
        code, _, err = run(capsys, *argv_for(cmd, inp, out, "-q"))
        one_error(code, err, cmd, str(out), case=f"unwritable output {out.parent} [{cmd}]")
        assert "sfm:" not in err and time.perf_counter() - t0 < 20
    assert listing(tmp_path) == before and blocker.read_text() == "x"


def test_debug_shows_the_traceback(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    from sparself.core.errors import InputError

    with pytest.raises(InputError, match="no scene found"):
        main(["info", str(tmp_path / "empty"), "--debug"])


# ---- train / synthesize: one tiny run shared by the cases ---------------------------------------------------


def _awkward_scene() -> Scene:
    """6 views, 2 and 3 at the same pose; 01 gray, 02 RGBA, 03 16-bit, 04 EXIF-rotated, 05 at twice
    the resolution (its own camera, same aspect ratio)."""
    s = make_scene(6, same=(3,))
    s.cameras[2] = Camera.pinhole(2 * W, 2 * H, 2 * F)
    s.frames[5].camera_id = 2
    s.frames[5].image = texture(2 * H, 2 * W, 5)
    return s


def _make_awkward(folder: Path) -> Path:
    folder = write_posed(folder, _awkward_scene(), "colmap")
    img = folder / "images"
    rgb = {n: np.asarray(Image.open(img / n).convert("RGB")) for n in ("01.png", "02.png", "03.png", "04.png")}
    Image.fromarray(rgb["01.png"]).convert("L").save(img / "01.png")
    Image.fromarray(rgb["02.png"]).convert("RGBA").save(img / "02.png")
    Image.fromarray(rgb["03.png"][..., 0].astype(np.uint16) * 257).save(img / "03.png")
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(rgb["04.png"]).transpose(Image.Transpose.ROTATE_90).save(img / "04.png", exif=exif)
    return folder


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """train -> plan -> synthesize through the CLI on the awkward scene (read-only, hashed)."""
    need("train", "synthesize")
    import contextlib
    import io

    root = tmp_path_factory.mktemp("trained")
    scene = _make_awkward(root / "scene")
    hashes = {p: p.read_bytes() for p in scene.rglob("*") if p.is_file()}
    logs = {}
    for name, argv in (
        (
            "train",
            [
                "train",
                scene,
                "--out",
                root / "run",
                "--epochs",
                "1",
                "--size",
                "32",
                "--crop",
                "16",
                "--device",
                "cpu",
                "--batch-size",
                "6",
            ],
        ),
        ("plan", ["plan", scene, "--out", root / "plan.json", "--n-mid", "3", "--n-extra", "1"]),
        ("synthesize", ["synthesize", root / "run", "--plan", root / "plan.json", "--out", root / "dense"]),
    ):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # no division by zero on the identical poses
            code = main([str(a) for a in argv])
        logs[name] = err.getvalue()
        assert code == 0, logs[name]
    assert {p: p.read_bytes() for p in scene.rglob("*") if p.is_file()} == hashes  # inputs untouched
    return {
        "root": root,
        "scene": scene,
        "run": root / "run",
        "plan": root / "plan.json",
        "dense": root / "dense",
        "logs": logs,
    }


def test_training_converts_images_with_warnings(trained):
    err = trained["logs"]["train"]
    for name, what in (("01.png", "L image"), ("02.png", "RGBA image"), ("03.png", "16-bit")):
        assert any(name in ln and what in ln and "converted to RGB" in ln for ln in err.splitlines()), err
    rows = (trained["run"] / "train_log.csv").read_text().splitlines()
    assert len(rows) == 2 and np.isfinite(float(rows[1].split(",")[1]))


def test_synthesis_on_identical_poses_and_mixed_sizes(trained):
    """The dense scene: 6 + 4 views (one midpoint between the identical poses 2 and 3), all finite; the
    mixed sizes were resized with a warning."""
    assert (
        "different image sizes" in trained["logs"]["synthesize"]
        and f"resizing them to {W}x{H}" in trained["logs"]["synthesize"]
    )
    dense = read_scene(trained["dense"])
    assert len(dense) == 10 and sum(f.synthetic for f in dense.frames) == 4
    assert sum(f.name.endswith("_novel_0002.50.png") for f in dense.frames) == 1
    for i, f in enumerate(dense.frames):
        img = dense.load(i)
        assert np.all(np.isfinite(img)) and img.shape[:2] == (dense.camera(i).height, dense.camera(i).width)
    assert listing(trained["root"]) == ["dense", "plan.json", "run", "scene"]


def synth_failure(capsys, trained, tmp_path, *needles, run_dir=None, plan=None, out=None, extra=(), case=""):
    if out is None:
        out = tmp_path / "res" / "out"
        out.parent.mkdir(parents=True, exist_ok=True)
    watch = out.parent if out.parent.is_dir() else tmp_path
    # /proc gains and loses one numeric entry per process while the test runs; sparself's names are never numeric
    entries = (
        (lambda: [n for n in listing(watch) if not n.isdigit()]) if watch == Path("/proc") else (lambda: listing(watch))
    )
    before = entries()
    code, _, err = run(
        capsys, "synthesize", run_dir or trained["run"], "--plan", plan or trained["plan"], "--out", out, "-q", *extra
    )
    line = one_error(code, err, "synthesize", *needles, case=case)
    assert entries() == before
    return line


def test_checkpoint_problems(trained, tmp_path, capsys):
    import torch

    other = tmp_path / "other_run"
    shutil.copytree(trained["run"], other)
    ck = torch.load(other / "checkpoint.pt", weights_only=False)
    ck["config"]["channels"] += 3  # a checkpoint from another config: every decoder layer changes shape
    torch.save(ck, other / "checkpoint.pt")
    synth_failure(
        capsys,
        trained,
        tmp_path,
        "checkpoint.pt",
        "does not fit this model",
        run_dir=other,
        case="checkpoint from another config [synthesize]",
    )
    (other / "checkpoint.pt").write_bytes(b"")
    synth_failure(
        capsys,
        trained,
        tmp_path,
        "checkpoint.pt",
        "cannot read checkpoint",
        run_dir=other,
        case="zero-byte checkpoint [synthesize]",
    )
    (other / "checkpoint.pt").write_bytes((trained["run"] / "checkpoint.pt").read_bytes()[:2000])
    synth_failure(
        capsys,
        trained,
        tmp_path,
        "checkpoint.pt",
        "cannot read checkpoint",
        run_dir=other,
        case="truncated checkpoint [synthesize]",
    )
    synth_failure(
        capsys,
        trained,
        tmp_path,
        "scene",
        "no checkpoint",
        run_dir=trained["scene"],
        case="not a run folder [synthesize]",
    )


def test_resume_with_another_config_is_refused(trained, tmp_path, capsys):
    run_dir = tmp_path / "run"
    shutil.copytree(trained["run"], run_dir)
    before = {p.name: p.read_bytes() for p in run_dir.iterdir()}
    code, _, err = run(
        capsys,
        "train",
        trained["scene"],
        "--out",
        run_dir,
        "--epochs",
        "2",
        "--size",
        "32",
        "--crop",
        "16",
        "--device",
        "cpu",
        "--batch-size",
        "6",
        "--decoder",
        "fc",
        "--resume",
        "-q",
    )
    one_error(
        code,
        err,
        "train",
        "checkpoint.pt",
        "different config",
        "decoder='sweep' (asked: 'fc')",
        case="--resume with another config [train]",
    )
    assert {p.name: p.read_bytes() for p in run_dir.iterdir()} == before  # the run is left as it was
    code, _, err = run(capsys, "train", trained["scene"], "--out", tmp_path / "none", "--resume", "-q")
    one_error(code, err, "train", "checkpoint.pt", "no checkpoint", case="--resume without a run [train]")


def _edit_plan(src: Path, dst: Path, edit) -> Path:
    doc = json.loads(src.read_text())
    edit(doc["frames"][1])
    dst.write_text(json.dumps(doc))
    return dst


@pytest.mark.parametrize(
    "case, edit, needles",
    [
        ("nan", lambda f: f["tvec"].__setitem__(0, float("nan")), ("invalid plan", "NaN")),
        ("shape", lambda f: f["qvec"].pop(), ("frame 1", "qvec must have 4 numbers, got 3")),
        ("camera", lambda f: f.__setitem__("camera_id", 7), ("frame 1", "camera 7 is not a camera of the scene")),
    ],
)
def test_bad_plan_file(trained, tmp_path, capsys, case, edit, needles):
    plan = _edit_plan(trained["plan"], tmp_path / "bad_plan.json", edit)
    synth_failure(capsys, trained, tmp_path, "bad_plan.json", *needles, plan=plan, case=f"plan {case} [synthesize]")


def test_mixed_aspect_ratios_are_refused(trained, tmp_path, capsys):
    s = _awkward_scene()  # the trained run's views and poses (synthesize refuses another scene first)
    s.cameras[3] = Camera.pinhole(H, H, F)
    s.frames[2].camera_id, s.frames[2].image = 3, texture(H, H, 2)
    scene = write_posed(tmp_path / "square", s, "colmap")
    check_failure(
        capsys,
        tmp_path / "t",
        "train",
        scene,
        "square",
        "different aspect ratios",
        f"{H}x{H}",
        case="mixed aspect [train]",
    )
    synth_failure(
        capsys,
        trained,
        tmp_path,
        "square",
        "different aspect ratios",
        f"{H}x{H}",
        f"{W}x{H}",
        extra=("--scene", scene),
        case="mixed aspect [synthesize]",
    )


def test_synthesize_output_folder(trained, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("keep me")
    synth_failure(capsys, trained, tmp_path, str(out), "--overwrite", out=out, case="existing output [synthesize]")
    assert (out / "old.txt").read_text() == "keep me"
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    synth_failure(
        capsys, trained, tmp_path, "a_file", "not a folder", out=blocker / "out", case="unwritable output [synthesize]"
    )
    synth_failure(
        capsys, trained, tmp_path, "/proc", out=Path("/proc/sparself_out"), case="read-only output [synthesize]"
    )
    # --overwrite replaces only a folder sparself wrote
    synth_failure(
        capsys,
        trained,
        tmp_path,
        str(out),
        "not a folder sparself wrote",
        out=out,
        extra=("--overwrite",),
        case="--overwrite on a folder sparself did not write [synthesize]",
    )
    (out / ".sparself-output").write_text("")
    code, _, err = run(
        capsys, "synthesize", trained["run"], "--plan", trained["plan"], "--out", out, "--overwrite", "-q"
    )
    assert code == 0, err
    assert not (out / "old.txt").exists() and (out / "transforms.json").is_file()


def test_memory_estimate_before_training(trained, caplog):
    """Logged by every training run (here: the fixture's); 500 views at 1024 px: the images alone need
    500 x 3 x 1024 x 768 float32 = 4.4 GiB, estimated from the cameras without decoding anything, and
    a machine with 8 GiB free gets a warning."""
    import torch

    from sparself.synthesis.train import log_memory_estimate, memory_estimate
    from sparself.synthesis.train_config import TrainConfig

    assert "INFO: training memory estimate: ~" in trained["logs"]["train"]
    cam = Camera.pinhole(4032, 3024, 3000.0)  # phone photos
    big = Scene(
        {1: cam},
        [
            Frame(
                f"{i:03d}.jpg",
                Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([i, 0.0, 0])),
                1,
                float(i),
                Path("/nonexistent") / f"{i:03d}.jpg",
            )
            for i in range(500)
        ],
    )
    est = memory_estimate(big.resized(1024), TrainConfig(size=1024), torch.device("cpu"))
    assert est["images"] == 500 * 3 * 1024 * 768 * 4 and est["total"] > est["images"]
    with caplog.at_level("INFO", logger="sparself"):
        log_memory_estimate(est, torch.device("cpu"), available=8 * 2**30)
    assert [r.levelname for r in caplog.records] == ["WARNING"] and "lower --size" in caplog.records[0].getMessage()


@pytest.mark.parametrize("what, file", [("IMAGE_ID", "images.txt"), ("CAMERA_ID", "cameras.txt")])
def test_a_repeated_id_in_a_text_model_is_one_line(tmp_path, capsys, what, file):
    folder = write_posed(tmp_path / "scene", make_scene(4), "colmap_text")
    path = folder / "sparse" / "0" / file
    lines = path.read_text().splitlines()
    data = [i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")]
    first, second = (data[0], data[2]) if file == "images.txt" else (data[0], data[0])
    if file == "cameras.txt":
        lines.insert(first + 1, lines[first])  # the one camera given twice
        second = first + 1
    else:
        lines[second] = "1 " + lines[second].split(" ", 1)[1]  # the second image takes the first one's id
    path.write_text("\n".join(lines) + "\n")
    code, _, err = run(capsys, "info", folder)
    line = one_error(code, err, "info", str(path), f"{what} 1")
    assert f"line {second + 1}" in line and f"line {first + 1}" in line and "Check failed" not in line
