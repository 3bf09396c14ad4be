"""Names from input files never lead outside --out, nor onto one another.

Explicit cases through the CLI for each reader and the plan loader; the seeded property test over
hundreds of mutated plan and pose files is in test_mutations.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sparself.core.errors import InputError
from sparself.core.names import check_names, name_problem
from test_bad_input import make_scene, one_error, run, write_posed
from test_output_safety import tree


@pytest.mark.parametrize(
    "name, problem",
    [
        ("../../x.png", "contains '..'"),
        ("..", "contains '..'"),
        ("/tmp/x.png", "absolute path"),
        ("C:x.png", "absolute path"),
        ("a\\b.png", "separator '\\'"),
        ("a/b.png", "separator '/'"),
        ("", "empty"),
        ("  ", "empty"),
        ("a\x00.png", "control character"),
        ("x" * 300 + ".png", "255 bytes"),
        (5, "is a int"),
        (None, "is a NoneType"),
        ("./a.png", "contains a path separator"),
    ],
)
def test_bad_names(name, problem):
    assert problem in name_problem(name)


def test_good_names_and_subfolders():
    for ok in ("00.png", "novel_0001.50.png", "é.jpg", ".hidden.png", "a..b.png"):
        assert name_problem(ok) is None, ok
    assert name_problem("cam1/00.png", subfolders=True) is None  # COLMAP image names may hold folders
    for bad in ("cam1/../../x.png", "/abs/x.png", "cam1//x.png", "./x.png"):
        assert name_problem(bad, subfolders=True) is not None, bad


def test_collisions_after_case_folding():
    check_names(["a.png", "b.png"], "f")
    with pytest.raises(InputError, match=r"f: image name 'A.PNG' and 'a.png' differ only in case"):
        check_names(["a.png", "A.PNG"], "f")
    with pytest.raises(InputError, match=r"f: image name 'a.png' appears twice"):
        check_names(["a.png", "a.png"], "f")
    with pytest.raises(InputError, match="does not end with an image extension"):
        check_names([".png"], "f", extensions=(".png",))
    with pytest.raises(InputError, match=r"f: frame name 'novel.png' is the name of a view of the scene \('Novel"):
        check_names(["a.png", "novel.png"], "f", what="frame name", taken=["Novel.png"])


# ---- through the CLI ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> dict:
    from test_output_safety import trained as make  # the same tiny run

    return make.__wrapped__(tmp_path_factory)


def _synth(capsys, trained, plan: Path, out: Path, *extra) -> tuple[int, str]:
    code, _, err = run(capsys, "synthesize", trained["run"], "--plan", plan, "--out", out, "-q", *extra)
    return code, err


@pytest.mark.parametrize(
    "name, needles",
    [
        ("../../escaped.png", ("frame name '../../escaped.png' contains '..'",)),
        ("/tmp/sparself_escaped.png", ("is an absolute path",)),
        ("sub/x.png", ("contains a path separator '/'",)),
        ("UPPER", ("differ only in case",)),  # frame 0's name in capitals
        ("00.PNG", ("frame name '00.PNG' is the name of a view of the scene ('00.png')",)),
        ("notes.txt", ("does not end with an image extension",)),
    ],
)
def test_plan_frame_names_are_checked_before_anything_is_written(trained, tmp_path, capsys, name, needles):
    doc = json.loads(trained["plan"].read_text())
    doc["frames"][1]["name"] = doc["frames"][0]["name"].upper() if name == "UPPER" else name
    plan = tmp_path / "plans" / "bad.json"
    plan.parent.mkdir()
    plan.write_text(json.dumps(doc))
    out = tmp_path / "a" / "b" / "out"
    before, tmp_before = tree(trained["root"]), tree(tmp_path)
    code, err = _synth(capsys, trained, plan, out)
    one_error(
        code, err, "synthesize", "bad.json", "frame name", *needles, case=f"plan frame name {name!r} [synthesize]"
    )
    assert tree(trained["root"]) == before and tree(tmp_path) == tmp_before
    assert not Path("/tmp/sparself_escaped.png").exists()


def _colmap_text(folder: Path, rename: dict) -> Path:
    from sparself.capture.io import read_scene
    from sparself.capture.io.colmap import write_colmap

    model = folder / "sparse" / "0"
    write_colmap(read_scene(folder), model, text=True)
    for p in model.glob("*.bin"):
        p.unlink()
    txt = model / "images.txt"
    body = txt.read_text()
    for a, b in rename.items():
        body = body.replace(f" {a}\n", f" {b}\n")
    txt.write_text(body)
    return txt


@pytest.mark.parametrize(
    "fmt, bad, needles",
    [
        ("colmap", "../../x.png", ("sparse/0", "image name '../../x.png' contains '..'")),
        ("colmap", "/etc/x.png", ("image name '/etc/x.png' is an absolute path",)),
        ("colmap", "01.PNG", ("image name", "differ only in case")),
        ("nerfstudio", "other/01.PNG", ("transforms.json", "image name", "differ only in case")),
        ("nerfstudio", "other/01.png", ("transforms.json", "image name '01.png' appears twice")),
        ("llff", "01.PNG", ("images", "differ only in case")),
        ("middlebury", "../01.png", ("scene_par.txt", "image name '../01.png' contains '..'")),
    ],
)
def test_image_names_in_pose_files(tmp_path, capsys, fmt, bad, needles):
    """Each reader refuses such names as it reads them, so every command does (shown with `info`)."""
    scene = write_posed(tmp_path / "data" / "scene", make_scene(6), "colmap" if fmt == "colmap" else fmt)
    if fmt == "colmap":
        _colmap_text(scene, {"00.png": bad})
        if bad == "01.PNG":
            (scene / "images" / "00.png").rename(scene / "images" / "01.PNG")
    elif fmt == "nerfstudio":
        js = scene / "transforms.json"
        doc = json.loads(js.read_text())
        doc["frames"][0]["file_path"] = bad
        js.write_text(json.dumps(doc))
        (scene / "other").mkdir()
        (scene / "other" / Path(bad).name).write_bytes((scene / "images" / "00.png").read_bytes())
    elif fmt == "llff":
        (scene / "images" / "00.png").rename(scene / "images" / "01.PNG")  # 01.png and 01.PNG
    else:
        par = scene / "scene_par.txt"
        par.write_text(par.read_text().replace("00.png ", f"{bad} ", 1))
        (scene / bad).write_bytes((scene / "00.png").read_bytes())  # a file there: otherwise it is skipped
    before = tree(tmp_path)
    code, _, err = run(capsys, "info", scene, "-q")
    one_error(code, err, "info", *needles, case=f"{fmt} image name {bad!r} [info]")
    assert tree(tmp_path) == before
