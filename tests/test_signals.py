"""SIGTERM (kill, timeout, container stop) and SIGHUP (closed terminal) behave like
Ctrl-C: temporary output removed, checkpoint kept, exit 128 + signal, one line saying how to go on."""

from __future__ import annotations

import shlex
import signal
import subprocess
import time
from pathlib import Path

import pytest

from test_bad_input import listing, make_scene, need, write_photos, write_posed
from test_robustness import DENSIFY, ENV, TRAIN, cli


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return write_posed(tmp_path_factory.mktemp("sig") / "scene", make_scene(6), "llff")


@pytest.fixture(scope="module")
def colmap_scene(tmp_path_factory) -> Path:
    """Read through pycolmap, whose import installs a native SIGTERM handler (a C++ stack, no cleanup)."""
    return write_posed(tmp_path_factory.mktemp("sigc") / "scene", make_scene(6), "colmap")


def _sigterm_under_timeout(argv: list, ready, what: str) -> str:
    """Run ``sparself argv`` under ``timeout``, send SIGTERM once ``ready()``; -> stderr (exit 143 checked)."""
    proc = subprocess.Popen(
        ["timeout", "-s", "KILL", "300", *cli(*argv)],
        env=ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    _wait_for(proc, ready, what)
    subprocess.run(["pkill", "-TERM", "-P", str(proc.pid)], check=True)  # the sparself under timeout
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "Traceback" not in err and "stack trace" not in err and "Aborted" not in err, err
    return err


def _wait_for(proc, cond, what: str) -> None:
    t0 = time.monotonic()
    while proc.poll() is None and time.monotonic() - t0 < 90 and not cond():
        time.sleep(0.01)
    assert proc.poll() is None, f"ended before {what}: {proc.communicate()[1]}"


def _densify_until(res: Path, scene: Path, ready: str, *more: str) -> subprocess.Popen:
    """``sparself densify scene --out res/out`` (500 epochs), once ``res/ready`` (a glob) exists."""
    argv = ["densify", scene, "--out", res / "out", "--epochs", "500", "--n-mid", "2", "--n-extra", "1", *DENSIFY]
    proc = subprocess.Popen(cli(*argv, *more), env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for(proc, lambda: list(res.glob(ready)), ready)
    return proc


def _interrupted(proc: subprocess.Popen, sig) -> str:
    """Send ``sig``; -> the one line saying what the interrupted command kept (exit 128 + sig, no traceback)."""
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig and "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if "interrupted" in ln]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_signal_during_densify_before_anything_is_finished_leaves_nothing(scene, tmp_path, sig):
    need("densify")
    res = tmp_path / "res"
    res.mkdir()
    proc = _densify_until(res, scene, ".out.sparself-work/runs/*/train_log.csv", "--checkpoint-every", "1000")
    line = _interrupted(proc, sig)
    name = signal.Signals(sig).name
    assert (
        line == f"sparself densify: interrupted by {name}; nothing was written to {res / 'out'}; run the command again"
    )
    assert listing(res) == []  # no output, no hidden temporary or work folder


def test_sigterm_during_densify_keeps_the_checkpoint_and_the_printed_command_continues(scene, tmp_path):
    need("densify")
    import torch

    res = tmp_path / "res"
    res.mkdir()
    work = res / ".out.sparself-work"
    proc = _densify_until(res, scene, ".out.sparself-work/runs/*/checkpoint.pt")
    line = _interrupted(proc, signal.SIGTERM)
    hint = (
        f"sparself densify: interrupted by SIGTERM; nothing was written to {res / 'out'}; the finished steps are "
        f"kept in {work}; continue with: "
    )
    assert line.startswith(hint), line
    assert listing(res) == [work.name]  # no output and no temporary folder: only the work folder
    [checkpoint] = work.glob("runs/*/checkpoint.pt")
    epoch = torch.load(checkpoint, weights_only=False)["epoch"]
    resume = shlex.split(line[len(hint) :])
    assert resume[-1] == "--resume" and resume.index("500")
    resume[resume.index("500")] = str(epoch + 1)  # the printed command, to a nearer end to keep the test short
    done = subprocess.run(cli(*resume[1:], "-q"), env=ENV, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert listing(res) == ["out"]  # the work folder goes once the scene is written
    assert torch.load(res / "out" / "run" / "checkpoint.pt", weights_only=False)["epoch"] == epoch + 1
    assert (res / "out" / "scene" / "sparself.json").is_file()


def test_sigterm_during_training_keeps_the_checkpoint_and_says_how_to_resume(scene, tmp_path):
    need("train")
    import torch

    run = tmp_path / "run"
    argv = ["train", str(scene), "--out", str(run), "--epochs", "500", *TRAIN]
    proc = subprocess.Popen(cli(*argv), env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for(proc, lambda: (run / "checkpoint.pt").exists(), "the first checkpoint")
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143 and "Traceback" not in err, err
    epoch = torch.load(run / "checkpoint.pt", weights_only=False)["epoch"]
    assert epoch >= 5
    hint = (
        f"sparself train: interrupted by SIGTERM; the checkpoint at epoch {epoch} is kept in "
        f"{run / 'checkpoint.pt'}; continue with: "
    )
    lines = [ln for ln in err.splitlines() if "interrupted" in ln]
    assert len(lines) == 1 and lines[0].startswith(hint), err
    resume = shlex.split(lines[0][len(hint) :])
    assert resume == ["sparself", *argv, "--resume"]
    assert not [p for p in [*tmp_path.iterdir(), *run.iterdir()] if ".tmp-" in p.name]  # no temporary file left
    # the printed command continues the run (here to a nearer end, to keep the test short)
    resume[resume.index("500")] = str(epoch + 1)
    done = subprocess.run(cli(*resume[1:], "-q"), env=ENV, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert torch.load(run / "checkpoint.pt", weights_only=False)["epoch"] == epoch + 1


def test_in_process_main_restores_the_signal_handlers(tmp_path, capsys):
    """main() installs its SIGTERM/SIGHUP handlers only while a command runs (tests call it in-process)."""
    from sparself.cli import main

    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)}
    main(["info", str(tmp_path / "missing"), "-q"])
    assert {s: signal.getsignal(s) for s in before} == before
    assert "no such file or folder" in capsys.readouterr().err


def test_sigterm_on_a_colmap_scene_is_ctrl_c_in_densify(colmap_scene, tmp_path):
    res = tmp_path / "res"
    res.mkdir()
    argv = ["densify", colmap_scene, "--out", res / "out", "--epochs", "500", "--n-mid", "2", "--n-extra", "1"]
    err = _sigterm_under_timeout(
        [*argv, *DENSIFY, "--checkpoint-every", "1000"],
        lambda: list(res.glob(".out.sparself-work/runs/*/train_log.csv")),
        "training started",
    )
    assert err.splitlines()[-1] == (
        f"sparself densify: interrupted by SIGTERM; nothing was written to {res / 'out'}; run the command again"
    )
    assert listing(res) == []


def test_sigterm_during_evaluate_keeps_its_checkpoints_and_the_printed_command_continues(scene, tmp_path):
    """``evaluate`` imports pycolmap (for its versions), whose native handler must not take SIGTERM over."""
    need("evaluate")
    res = tmp_path / "res"
    res.mkdir()
    argv = ["evaluate", scene, "--out", res / "out", "--quick", "--size", "32", "--inputs", "5", "--recon", "mpi"]
    argv += "--epochs 500 --seeds 1 --crop 16 --backbone-size 32 --device cpu --no-lpips".split()
    proc = subprocess.Popen(cli(*argv), env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for(proc, lambda: list(res.glob(".out.sparself-work/runs/*/checkpoint.pt")), "the first checkpoint")
    line = _interrupted(proc, signal.SIGTERM)
    work = res / ".out.sparself-work"
    hint = (
        f"sparself evaluate: interrupted by SIGTERM; nothing was written to {res / 'out'}; the finished steps are "
        f"kept in {work}; continue with: "
    )
    assert line.startswith(hint), line
    assert listing(res) == [work.name]
    resume = shlex.split(line[len(hint) :])
    resume[resume.index("500")] = "6"  # the printed command, to a nearer end to keep the test short
    done = subprocess.run(cli(*resume[1:], "-q"), env=ENV, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert listing(res) == ["out"] and (res / "out" / "results.json").is_file()


def test_sigterm_on_a_colmap_scene_is_ctrl_c_in_train(colmap_scene, tmp_path):
    run = tmp_path / "run"
    argv = ["train", colmap_scene, "--out", run, "--epochs", "500", *TRAIN]
    err = _sigterm_under_timeout(argv, lambda: (run / "checkpoint.pt").exists(), "the first checkpoint")
    assert err.splitlines()[-1].startswith("sparself train: interrupted by SIGTERM; the checkpoint at epoch")


def test_sigterm_during_sfm_removes_its_scratch_folder(tmp_path):
    """SfM's database and undistorted copies live beside --out, named as its temporary folders (a later run
    removes them if this one is killed), and SIGTERM removes them with the rest."""
    write_photos(tmp_path / "photos", 12, size=(640, 480))
    res = tmp_path / "res"
    res.mkdir()
    argv = ["poses", tmp_path / "photos", "--out", res / "out"]
    err = _sigterm_under_timeout(argv, lambda: list(res.glob(".out.tmp-*-sfm-*/*")), "SfM started")
    assert err.splitlines()[-1].startswith("sparself poses: interrupted by SIGTERM"), err
    assert listing(res) == []
