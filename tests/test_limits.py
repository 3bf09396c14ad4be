"""Limits a user can hit, each said in one line with nothing left behind: a --holdout past the last view,
a path part over the file system's 255 bytes, a full disk, a --out-size that is not a size."""

from __future__ import annotations

import errno
import os
import shutil
from collections import namedtuple

import pytest

from sparself.capture import io as sio
from sparself.core.outputs import atomic_dir
from test_bad_input import listing, make_scene, need, one_error, run, write_photos, write_posed
from test_robustness import DENSIFY

Usage = namedtuple("Usage", "total used free")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return write_posed(tmp_path_factory.mktemp("lim") / "scene", make_scene(6), "llff")


def test_holdout_past_the_last_view_is_one_line(scene, tmp_path, capsys):
    need("densify")
    code, _, err = run(capsys, "densify", scene, "--out", tmp_path / "out", "--holdout", "6", *DENSIFY)
    one_error(code, err, "densify", "--holdout 6", "6 views", "positions 0 to 5")
    assert listing(tmp_path) == []


@pytest.mark.parametrize("size", ["0", "-5", "big"])
def test_out_size_that_is_not_a_size_is_refused_when_parsing(tmp_path, capsys, size):
    with pytest.raises(SystemExit) as e:
        run(capsys, "densify", tmp_path / "no-photos-needed", "--out", tmp_path / "out", "--out-size", size)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--out-size: expected a whole number of pixels above 0" in err and "Traceback" not in err


def test_an_input_path_part_over_255_bytes_is_one_line(tmp_path, capsys):
    long = tmp_path / ("x" * 300) / "scene"
    code, _, err = run(capsys, "info", long)
    one_error(code, err, "info", "longer than the file system allows (255 bytes)")


def test_a_legal_long_out_name_is_written(tmp_path):
    """240 bytes is a legal name: the hidden temporary folder and lock beside it must fit too."""
    out = tmp_path / ("o" * 240)
    with atomic_dir(out) as tmp:
        (tmp / "x.txt").write_text("x")
    assert (out / "x.txt").read_text() == "x"
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


def test_poses_checks_free_space_before_sfm(tmp_path, capsys, monkeypatch):
    need("poses")
    write_photos(tmp_path / "photos", 4)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**9, 10**9 - 10**6, 10**6))
    code, _, err = run(capsys, "poses", tmp_path / "photos", "--out", tmp_path / "out")
    line = one_error(code, err, "poses", "no space left on ", "needed about 64 MB", "1 MB free")
    assert "sfm:" not in err, line
    assert listing(tmp_path) == ["photos"]


def test_a_disk_that_fills_up_during_densify_is_one_line(scene, tmp_path, capsys, monkeypatch):
    need("densify")

    def full(*a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "out"))

    monkeypatch.setattr(sio, "write_scene_into", full)
    argv = ["densify", scene, "--out", tmp_path / "out", "--epochs", "1", "--n-mid", "1", "--n-extra", "0", *DENSIFY]
    code, _, err = run(capsys, *argv)
    one_error(code, err, "densify", "no space left on ", "needed about")
    # the temporary output is removed; the finished steps are kept for --resume, once space is freed
    assert listing(tmp_path) == [".out.sparself-work"]
    assert f"the finished steps are kept in {tmp_path / '.out.sparself-work'}; the same command with --resume" in err


def test_a_full_disk_under_torch_save_becomes_the_disk_error(tmp_path, monkeypatch):
    """torch.save reports a full disk as a RuntimeError; the checkpoint writer says what it is."""
    from sparself.core.outputs import atomic_file

    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**9, 10**9, 0))
    with pytest.raises(OSError) as e:
        with atomic_file(tmp_path / "checkpoint.pt"):
            raise RuntimeError("[enforce fail at inline_container.cc:603] . PytorchStreamWriter failed writing file")
    assert e.value.errno == errno.ENOSPC and listing(tmp_path) == []
