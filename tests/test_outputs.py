"""Atomic outputs: nothing partial is left behind, existing results are not clobbered silently."""

from __future__ import annotations

import pytest

from sparself.core.errors import OutputError
from sparself.core.outputs import MARKER, atomic_dir, atomic_file


def test_atomic_dir_success_and_failure(tmp_path):
    out = tmp_path / "res"
    with atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("ok")
        assert not out.exists()
    assert (out / "a.txt").read_text() == "ok" and (out / MARKER).is_file()
    assert [p.name for p in tmp_path.iterdir()] == ["res"]  # temp folder renamed, nothing else left

    out2 = tmp_path / "res2"
    with pytest.raises(RuntimeError):
        with atomic_dir(out2) as tmp:
            (tmp / "half.txt").write_text("partial")
            raise RuntimeError("boom")
    assert not out2.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]


def test_atomic_dir_refuses_non_empty_unless_overwrite(tmp_path):
    out = tmp_path / "res"
    out.mkdir()
    (out / "old.txt").write_text("keep")
    with pytest.raises(OutputError, match="not empty.*--overwrite"):
        with atomic_dir(out):
            pass
    assert (out / "old.txt").read_text() == "keep"
    with pytest.raises(OutputError, match="not a folder sparself wrote"):  # --overwrite: not ours
        with atomic_dir(out, overwrite=True):
            pass
    assert (out / "old.txt").read_text() == "keep"
    (out / MARKER).write_text("")
    with atomic_dir(out, overwrite=True) as tmp:
        (tmp / "new.txt").write_text("n")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "new.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]


def test_atomic_file(tmp_path):
    p = tmp_path / "plan.json"
    with pytest.raises(ValueError):
        with atomic_file(p) as tmp:
            tmp.write_text("{")
            raise ValueError
    assert list(tmp_path.iterdir()) == []
    with atomic_file(p) as tmp:
        tmp.write_text("{}")
    assert p.read_text() == "{}" and len(list(tmp_path.iterdir())) == 1


# ---- outputs that cannot be renamed or deleted ------------------------------------

import errno  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
from pathlib import Path  # noqa: E402


def _old_output(tmp_path):
    out = tmp_path / "res"
    out.mkdir()
    (out / MARKER).write_text("")
    (out / "old.txt").write_text("old")
    (out / "sub").mkdir()
    (out / "sub" / "old2.txt").write_text("old")
    return out


def _write_result(tmp):
    (tmp / "a.txt").write_text("new")
    (tmp / "images").mkdir()
    (tmp / "images" / "0.png").write_bytes(b"png")


def _is_result(out):
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [MARKER, "a.txt", "images", "images/0.png"]
    assert (out / "a.txt").read_text() == "new" and (out / "images" / "0.png").read_bytes() == b"png"


def test_mount_point_is_filled_in_place(tmp_path, monkeypatch):
    """A mount point cannot be renamed or removed: the temporary folder goes inside it and its entries are
    renamed into place one by one; a failure leaves the old content as it was."""
    out = _old_output(tmp_path)
    real_ismount = os.path.ismount
    monkeypatch.setattr(os.path, "ismount", lambda p: Path(p) == out or real_ismount(p))
    with pytest.raises(RuntimeError):
        with atomic_dir(out, overwrite=True) as tmp:
            assert tmp.parent == out  # inside the mount point
            _write_result(tmp)
            raise RuntimeError("boom")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "old.txt", "sub"]
    with atomic_dir(out, overwrite=True) as tmp:
        _write_result(tmp)
    _is_result(out)
    assert [p.name for p in tmp_path.iterdir()] == ["res"]


@pytest.mark.parametrize("err", [errno.EBUSY, errno.EXDEV])
def test_output_that_cannot_be_renamed_is_written_entry_by_entry(tmp_path, monkeypatch, err):
    """os.rename of the output folder fails (EBUSY: a mount point not seen as one; EXDEV: another file
    system); moving the temporary folder's entries into it then fails with EXDEV too, so they are copied to
    a temporary name inside the output and renamed from there: every file appears whole."""
    out = _old_output(tmp_path)
    real_rename, real_replace = os.rename, os.replace
    renames = []

    def rename(src, dst, _real=real_rename):
        src, dst = Path(src), Path(dst)
        if out in (src, dst):
            raise OSError(err, os.strerror(err))
        if src.parent != out and dst.parent == out and not src.name.startswith("."):
            raise OSError(errno.EXDEV, os.strerror(errno.EXDEV))  # from the sibling into the output
        if dst.parent == out:
            renames.append(dst.name)
        return _real(src, dst)

    monkeypatch.setattr(os, "rename", rename)
    monkeypatch.setattr(os, "replace", lambda s, d: rename(s, d, real_replace))
    with atomic_dir(out, overwrite=True) as tmp:
        assert tmp.parent == tmp_path
        _write_result(tmp)
    _is_result(out)
    assert [p.name for p in tmp_path.iterdir()] == ["res"]
    assert sorted(renames) == sorted([MARKER, "a.txt", "images"])  # each entry renamed into place


def test_overwrite_of_a_folder_that_cannot_be_deleted_fails_up_front(tmp_path, monkeypatch):
    out = _old_output(tmp_path)
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: Path(p) != out / "sub" and real_access(p, mode, **kw))
    with pytest.raises(OutputError, match=r"--overwrite cannot delete it: no permission to change .*sub"):
        with atomic_dir(out, overwrite=True):
            pytest.fail("the refusal must come before the work")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "old.txt", "sub"]


@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("chattr"), reason="needs root and chattr")
def test_overwrite_of_an_immutable_file_fails_up_front(tmp_path):
    out = _old_output(tmp_path)
    if subprocess.run(["chattr", "+i", str(out / "sub" / "old2.txt")], capture_output=True).returncode:
        pytest.skip("chattr +i not permitted here")
    try:
        with pytest.raises(OutputError, match=r"old2.txt is protected"):
            with atomic_dir(out, overwrite=True):
                pytest.fail("the refusal must come before the work")
    finally:
        subprocess.run(["chattr", "-i", str(out / "sub" / "old2.txt")], check=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]


def test_symlinked_output_writes_where_it_points(tmp_path):
    target = _old_output(tmp_path)
    link = tmp_path / "link"
    link.symlink_to(target)
    with atomic_dir(link, overwrite=True) as tmp:
        _write_result(tmp)
    assert link.is_symlink() and link.resolve() == target
    _is_result(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "res"]
