"""One writer per output: a second command into the same --out is refused, and what appears at --out
while a command runs (a user's folder, a file) is never replaced or deleted by the final swap."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from sparself.core.errors import OutputError
from sparself.core.locks import lock_path, output_lock
from sparself.core.outputs import MARKER, atomic_dir
from test_bad_input import one_error, run


def test_a_folder_that_appears_at_out_meanwhile_is_kept(tmp_path):
    out = tmp_path / "D"
    with pytest.raises(OutputError, match="something else was put there") as e:
        with atomic_dir(out) as tmp:
            (tmp / "result.txt").write_text("new")
            out.mkdir()
            (out / "notes.txt").write_text("precious")
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert (out / "notes.txt").read_text() == "precious"
    kept = Path(str(e.value).rsplit("the result is in ", 1)[1])
    assert (kept / "result.txt").read_text() == "new" and (kept / MARKER).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["D", kept.name])  # no temp or lock left


def test_a_file_that_appears_at_out_meanwhile_is_kept(tmp_path):
    out = tmp_path / "D"
    with pytest.raises(OutputError, match="something else was put there"):
        with atomic_dir(out):
            out.write_text("precious")
    assert out.read_text() == "precious"


def test_overwrite_keeps_a_folder_that_replaced_the_old_output_meanwhile(tmp_path):
    """--overwrite replaces the sparself folder it checked at the start, not one moved there since."""
    out = tmp_path / "D"
    out.mkdir()
    (out / MARKER).write_text("")
    with pytest.raises(OutputError, match="something else was put there"):
        with atomic_dir(out, overwrite=True):
            out.rename(tmp_path / "moved")
            out.mkdir()
            (out / "notes.txt").write_text("precious")
    assert (out / "notes.txt").read_text() == "precious"
    assert (tmp_path / "moved" / MARKER).is_file()


def test_an_empty_folder_that_appears_meanwhile_is_replaced(tmp_path):
    out = tmp_path / "D"
    with atomic_dir(out) as tmp:
        (tmp / "result.txt").write_text("new")
        out.mkdir()
    assert (out / "result.txt").read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["D"]


def _hold_lock(out: Path) -> subprocess.Popen:
    """Another process holding the lock of ``out`` (as a running sparself command does)."""
    code = f"from sparself.core.locks import output_lock\nimport time\nwith output_lock({str(out)!r}):\n"
    code += "    print('held', flush=True)\n    time.sleep(60)\n"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


@pytest.mark.parametrize("cmd", ["train", "densify", "plan", "poses"])
def test_a_second_writer_into_the_same_out_is_refused(tmp_path, capsys, cmd):
    out = tmp_path / "a" / "D"
    proc = _hold_lock(out)
    try:
        code, _, err = run(capsys, cmd, tmp_path / "missing", "--out", out)
        line = one_error(code, err, cmd, str(out), f"another sparself command (process {proc.pid})")
        assert "is writing it" in line
    finally:
        proc.kill()
        proc.wait()
    assert not out.exists() and lock_path(out).is_file()  # SIGKILL: the file stays, its lock went with the holder
    code, _, err = run(capsys, cmd, tmp_path / "missing", "--out", out)  # the holder has gone: the usual check
    one_error(code, err, cmd, "missing")
    assert "lock" not in err and "another sparself command" not in err  # taken over without a word
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a"]  # a killed holder's lock file is taken over and removed


def test_the_lock_is_shared_by_nested_holds_and_leaves_nothing(tmp_path):
    out = tmp_path / "new" / "D"
    with output_lock(out):
        assert lock_path(out).is_file()
        with atomic_dir(out) as tmp:  # atomic_dir takes the same lock again
            (tmp / "x").write_text("x")
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == ["D"]
    with output_lock(tmp_path / "other" / "D"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new"]  # created parents removed again


def test_overwrite_names_what_a_user_added_to_a_sparself_output(tmp_path, caplog):
    import logging

    out = tmp_path / "D"
    with atomic_dir(out) as tmp:
        (tmp / "scene").mkdir()
    (out / "notes.txt").write_text("mine")
    with caplog.at_level(logging.WARNING, logger="sparself"):
        with atomic_dir(out, overwrite=True) as tmp:
            (tmp / "scene").mkdir()
    said = [r.getMessage() for r in caplog.records]
    assert said == [f"{out}: --overwrite also removes 1 entry sparself did not write there: notes.txt"]
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "scene"]


def test_plan_overwrite_replaces_only_a_plan(tmp_path, capsys):
    from test_bad_input import make_scene, write_posed

    scene = write_posed(tmp_path / "scene", make_scene(5), "llff")
    other = tmp_path / "afile.txt"
    other.write_text("my notes")
    code, _, err = run(capsys, "plan", scene, "--out", other, "--overwrite")
    one_error(code, err, "plan", str(other), "not a plan sparself wrote")
    assert other.read_text() == "my notes"
    plan = tmp_path / "plan.json"
    for _ in range(2):  # a plan is replaced
        code, _, err = run(capsys, "plan", scene, "--out", plan, "--overwrite", "-q")
        assert code == 0, err
