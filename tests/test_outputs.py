"""Atomic outputs: nothing partial is left behind, existing results are not clobbered silently."""

from __future__ import annotations

import pytest

from sparself.errors import OutputError
from sparself.outputs import atomic_dir, atomic_file


def test_atomic_dir_success_and_failure(tmp_path):
    out = tmp_path / "res"
    with atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("ok")
        assert not out.exists()
    assert (out / "a.txt").read_text() == "ok"
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
    with atomic_dir(out, overwrite=True) as tmp:
        (tmp / "new.txt").write_text("n")
    assert [p.name for p in out.iterdir()] == ["new.txt"]


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
