"""`sparself info` and `sparself plan` end to end on the bundled sample scene, and their bad inputs."""

from __future__ import annotations

import json
import logging
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sparself.cli import main

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "bird"
SHARED_BIRD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "llff_bird"


def run(capsys, *argv):
    try:
        code = main([str(a) for a in argv])
    finally:
        # main() points the root logger at this test's captured stderr; detach it so later tests do
        # not log into a closed stream
        root = logging.getLogger()
        for h in [h for h in root.handlers if type(h) is logging.StreamHandler]:
            root.removeHandler(h)
    out, err = capsys.readouterr()
    return code, out, err


def error_lines(err: str) -> list[str]:
    assert "Traceback" not in err
    return [line for line in err.splitlines() if "error" in line]


@pytest.fixture
def sample_copy(tmp_path) -> Path:
    dst = tmp_path / "bird"
    shutil.copytree(SAMPLE, dst)
    return dst


def test_sample_scene_is_what_attribution_says():
    names = sorted(p.name for p in (SAMPLE / "images").iterdir())
    pb = np.load(SAMPLE / "poses_bounds.npy")
    expected = [f"{i + 1:03d}.jpg" for i in np.round(np.linspace(0, 183, 49)).astype(int)]
    assert names == expected and pb.shape == (49, 17)
    with Image.open(SAMPLE / "images" / names[0]) as im:
        assert im.size == (272, 480)
    assert np.allclose(pb[:, [4, 9]], [480, 272]) and np.all(np.isfinite(pb))
    assert (SAMPLE / "ATTRIBUTION.md").is_file()
    assert sum(p.stat().st_size for p in SAMPLE.rglob("*") if p.is_file()) < 3_000_000


def test_sample_rows_match_the_source_capture():
    if not (SHARED_BIRD / "poses_bounds.npy").is_file():
        pytest.skip(f"{SHARED_BIRD} not found")
    src = np.load(SHARED_BIRD / "poses_bounds.npy")
    ours = np.load(SAMPLE / "poses_bounds.npy")
    keep = np.round(np.linspace(0, len(src) - 1, 49)).astype(int)
    same = [c for c in range(17) if c not in (4, 9, 14)]  # all but hwf
    assert np.array_equal(ours[:, same], src[keep][:, same])
    assert np.allclose(ours[:, [4, 9, 14]], src[keep][:, [4, 9, 14]] / 2)


def test_info_on_sample(capsys):
    code, out, err = run(capsys, "info", SAMPLE, "-q")
    assert code == 0, err
    f = float(np.load(SAMPLE / "poses_bounds.npy")[0, 14])
    fov_h, fov_v = (math.degrees(2 * math.atan(s / (2 * f))) for s in (272, 480))
    assert "views:         49" in out
    assert "272x480" in out and "SIMPLE_PINHOLE" in out
    assert f"{fov_h:.2f} x {fov_v:.2f} deg" in out
    assert "depth bounds" in out and "scene scale" in out

    code, out, _ = run(capsys, "info", SAMPLE, "--json", "-q")
    info = json.loads(out)
    assert code == 0 and info["views"] == 49 and info["sizes"] == ["272x480"]
    assert info["cameras"]["1"]["fov_deg"] == pytest.approx([fov_h, fov_v], abs=1e-3)
    pb = np.load(SAMPLE / "poses_bounds.npy")
    centres = pb[:, :15].reshape(-1, 3, 5)[:, :, 3]  # LLFF column 3 = camera centre in world
    assert info["centers"]["min"] == pytest.approx(centres.min(0).tolist(), abs=1e-9)
    assert info["depth_bounds"] == pytest.approx([pb[:, 15].min(), pb[:, 16].max()], rel=1e-6)


def test_plan_with_plot_on_sample(tmp_path, capsys):
    out = tmp_path / "out" / "plan.json"
    png = tmp_path / "out" / "cams.png"
    code, stdout, err = run(capsys, "plan", SAMPLE, "--out", out, "--plot", png, "-q")
    assert code == 0, err
    doc = json.loads(out.read_text())
    idx = [f["index"] for f in doc["frames"]]
    assert len(idx) == 10 and doc["config"]["n_mid"] == 8
    assert idx[0] == pytest.approx(-0.2) and idx[-1] == pytest.approx(48.2)
    assert sum(1 for i in idx if 0 < i < 48 and i % 1 == 0.5) == 8
    with Image.open(png) as im:
        assert im.format == "PNG" and im.size[0] > 200
        # not a blank canvas: the orange planned frusta are drawn
        rgb = np.asarray(im.convert("RGB")).astype(int)
        assert np.sum((rgb[..., 0] > 200) & (rgb[..., 1] > 100) & (rgb[..., 1] < 160) & (rgb[..., 2] < 80)) > 300
    assert "planned 10 novel poses" in stdout
    # counts are configurable from the command line
    code, _, _ = run(capsys, "plan", SAMPLE, "--out", out, "--n-mid", "4", "--n-extra", "0", "--overwrite", "-q")
    assert code == 0 and len(json.loads(out.read_text())["frames"]) == 4


def test_plan_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "plan.json"
    out.write_text("keep me")
    code, _, err = run(capsys, "plan", SAMPLE, "--out", out, "-q")
    assert code != 0 and len(error_lines(err)) == 1 and "plan.json" in err and "--overwrite" in err
    assert out.read_text() == "keep me"


def _bad_input_case(tmp_path, capsys, scene: Path, needle: str):
    out = tmp_path / "res" / "plan.json"
    for argv in (["info", scene, "-q"], ["plan", scene, "--out", out, "--plot", tmp_path / "res" / "c.png", "-q"]):
        code, stdout, err = run(capsys, *argv)
        lines = error_lines(err)
        assert code != 0
        assert len(lines) == 1 and needle in lines[0], err
        assert not (tmp_path / "res").exists() or not any((tmp_path / "res").iterdir())


def test_missing_path(tmp_path, capsys):
    _bad_input_case(tmp_path, capsys, tmp_path / "no_such_scene", "no_such_scene")


def test_empty_folder(tmp_path, capsys):
    (tmp_path / "empty_scene").mkdir()
    _bad_input_case(tmp_path, capsys, tmp_path / "empty_scene", "empty_scene")


def test_nan_pose_file(tmp_path, capsys, sample_copy):
    pb = np.load(sample_copy / "poses_bounds.npy")
    pb[5, 7] = np.nan
    np.save(sample_copy / "poses_bounds.npy", pb)
    before = (sample_copy / "poses_bounds.npy").read_bytes()
    _bad_input_case(tmp_path, capsys, sample_copy, "poses_bounds.npy")
    assert (sample_copy / "poses_bounds.npy").read_bytes() == before  # input untouched


def test_wrong_shape_pose_file(tmp_path, capsys, sample_copy):
    np.save(sample_copy / "poses_bounds.npy", np.load(sample_copy / "poses_bounds.npy")[:, :15])
    _bad_input_case(tmp_path, capsys, sample_copy, "poses_bounds.npy")


def test_two_views_cannot_be_planned(tmp_path, capsys, sample_copy):
    names = sorted(p.name for p in (sample_copy / "images").iterdir())
    for n in names[2:]:
        (sample_copy / "images" / n).unlink()
    np.save(sample_copy / "poses_bounds.npy", np.load(sample_copy / "poses_bounds.npy")[:2])
    out = tmp_path / "plan.json"
    code, _, err = run(capsys, "plan", sample_copy, "--out", out, "-q")
    lines = error_lines(err)
    assert code != 0 and len(lines) == 1 and "3" in lines[0] and "bird" in lines[0]
    assert not out.exists()


def test_unusable_output_paths(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    code, _, err = run(capsys, "plan", SAMPLE, "--out", blocker / "plan.json", "-q")
    lines = error_lines(err)
    assert code != 0 and len(lines) == 1 and "a_file" in lines[0]
    code, _, err = run(capsys, "plan", SAMPLE, "--out", tmp_path / "p.json", "--plot", tmp_path / "c.jpg", "-q")
    assert code != 0 and ".png" in err and not (tmp_path / "p.json").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]  # no temporary files left behind


def test_plot_draws_held_out_views(tmp_path):
    from sparself.capture.io import read_scene
    from sparself.capture.plot import plot_cameras

    scene = read_scene(SAMPLE)
    inputs, held = scene.subset(list(range(0, 49, 2))), [scene.frames[i] for i in range(1, 49, 2)]

    def green(path):
        rgb = np.asarray(Image.open(path).convert("RGB")).astype(int)
        return int(np.sum((rgb[..., 1] > 120) & (rgb[..., 0] < 90) & (rgb[..., 2] < 90)))  # tab:green

    plot_cameras(inputs, planned=None, held_out=held, path=tmp_path / "with.png")
    plot_cameras(inputs, path=tmp_path / "without.png")
    assert green(tmp_path / "with.png") > 300 and green(tmp_path / "without.png") == 0


def test_a_removed_command_fails_the_tests_that_need_it(monkeypatch):
    """test_bad_input.need() fails (never skips) when a command the suite exercises is gone."""
    import test_bad_input

    monkeypatch.setattr(test_bad_input, "AVAILABLE", test_bad_input.AVAILABLE - {"train"})
    with pytest.raises(AssertionError, match="sparself train"):
        test_bad_input.need("plan", "train")
    test_bad_input.need("plan")


@pytest.mark.parametrize(("user", "expected"), [(None, None), ("123", "123")])
def test_a_command_shortens_the_openmp_spin_before_torch_loads_and_keeps_a_users_own(user, expected):
    """torch's spinning OpenMP threads take the cores from the fit workers beside them; libgomp reads its
    setting once, when torch loads, so the command must set it first, and never over the user's."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "GOMP_SPINCOUNT"} | ({"GOMP_SPINCOUNT": user} if user else {})
    code = (
        "import os, sys\n"
        "from sparself import cli\n"
        "assert 'torch' not in sys.modules\n"
        "cli.main([])\n"
        "import torch\n"
        "print('spin', os.environ.get('GOMP_SPINCOUNT'))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    from sparself.cli import OPENMP_SPIN

    assert out.splitlines()[-1] == f"spin {expected or OPENMP_SPIN}"


def test_a_process_with_torch_loaded_keeps_its_environment(monkeypatch):
    """In-process callers (a notebook, the tests) have loaded torch already: setting the spin then would do
    nothing but leak into their environment."""
    import os

    import torch  # noqa: F401 - loaded, as in such a caller

    from sparself import cli

    monkeypatch.delenv("GOMP_SPINCOUNT", raising=False)
    cli.short_openmp_spin()
    assert "GOMP_SPINCOUNT" not in os.environ
