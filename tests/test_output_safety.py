"""No command ever writes into or over one of its inputs, and --overwrite replaces
only a folder sparself wrote (or an empty one).

Every case runs through the CLI with --overwrite (the dangerous flag) and checks: exactly one error line
naming the output and the input, and the whole surrounding tree byte-identical afterwards (so the inputs
are untouched and no output or temporary folder was created: the refusal came before any work)."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

from sparself.core.outputs import MARKER
from test_bad_input import make_scene, need, one_error, run, write_photos, write_posed

TINY = [
    "--epochs",
    "1",
    "--size",
    "32",
    "--crop",
    "16",
    "--backbone-size",
    "32",
    "--device",
    "cpu",
    "--batch-size",
    "6",
    "--weights",
    "none",
]
TINY_DENSIFY = TINY[: 1 + 1] + TINY[4:] + ["--recon", "none"]  # no --size: densify trains at the photos' size


def tree(root: Path) -> dict:
    """Every entry under ``root`` (hidden ones too, symlinks not followed): content hash, link target or 'dir'."""
    out = {}
    for d, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(d) / name
            rel = str(p.relative_to(root))
            if p.is_symlink():
                out[rel] = "-> " + os.readlink(p)
            elif p.is_file():
                out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
            else:
                out[rel] = "dir"
    return out


def out_for(relation: str, target: Path, root: Path, monkeypatch, file_name: str = "") -> Path:
    """The --out that stands in ``relation`` to ``target``: the same path, its parent, a child, ``.`` with
    the working directory there, or a symlink to it."""
    if relation == "same":
        return target
    if relation == "parent":
        return target.parent
    if relation == "child":
        return target / (file_name or "out") if target.is_dir() else target.parent / "out"
    if relation == "dot":
        monkeypatch.chdir(target if target.is_dir() else target.parent)
        return Path(".")
    if relation == "symlink":
        link = root / "link"
        link.symlink_to(target)
        return link
    raise KeyError(relation)


RELATIONS = ["same", "parent", "child", "dot", "symlink"]


def refused(capsys, root: Path, cmd: str, argv: list, *needles: str, case: str = "", overwrite: bool = True) -> str:
    before = tree(root)
    code, _, err = run(capsys, *argv, *(["--overwrite"] if overwrite else []), "-q")
    line = one_error(code, err, cmd, *needles, case=case)
    assert tree(root) == before, f"{cmd}: the tree changed"
    assert "sfm:" not in err and "training memory" not in err  # refused before any work
    return line


@pytest.fixture
def root(tmp_path) -> Path:
    r = tmp_path / "root"
    r.mkdir()
    return r


def _how(relation: str) -> str:
    return {
        "same": " is the ",
        "parent": " contains the ",
        "child": " lies inside the ",
        "dot": " the ",
        "symlink": " is the ",
    }[relation]


@pytest.mark.parametrize("relation", RELATIONS)
@pytest.mark.parametrize("cmd", ["poses", "densify"])
def test_photo_folder_is_never_the_output(root, capsys, monkeypatch, cmd, relation):
    need(cmd)
    photos = write_photos(root / "photos", 3)[0].parent
    out = out_for(relation, photos, root, monkeypatch)
    extra = ["--link-images"] if cmd == "poses" else TINY_DENSIFY
    refused(
        capsys,
        root,
        cmd,
        [cmd, photos, "--out", out, *extra],
        f"output {out}",
        _how(relation),
        "photos",
        "choose an --out outside",
        case=f"--out {relation} photo folder [{cmd}]",
    )


@pytest.mark.parametrize("relation", RELATIONS)
@pytest.mark.parametrize("cmd", ["plan", "train", "densify", "evaluate"])
def test_scene_folder_is_never_the_output(root, capsys, monkeypatch, cmd, relation):
    need(cmd)
    scene = write_posed(root / "scene", make_scene(6), "llff")
    out = out_for(relation, scene, root, monkeypatch, "plan.json" if cmd == "plan" else "out")
    extra = {"plan": [], "train": TINY, "densify": TINY_DENSIFY, "evaluate": ["--quick", "--recon", "mpi"]}[cmd]
    refused(
        capsys,
        root,
        cmd,
        [cmd, scene, "--out", out, *extra],
        f"output {out}",
        _how(relation),
        "scene",
        case=f"--out {relation} scene folder [{cmd}]",
    )


@pytest.mark.parametrize("relation", ["same", "parent"])
def test_pose_file_is_never_the_output(root, capsys, monkeypatch, relation):
    """A scene given by its pose file: the file and the folder holding it (with the images) are inputs."""
    need("train")
    npy = write_posed(root / "scene", make_scene(6), "llff") / "poses_bounds.npy"
    out = out_for(relation, npy, root, monkeypatch)
    refused(
        capsys,
        root,
        "train",
        ["train", npy, "--out", out, *TINY],
        f"output {out}",
        "poses_bounds.npy",
        case=f"--out {relation} pose file [train]",
    )


def test_plot_and_plan_file_are_different_outputs(root, capsys):
    scene = write_posed(root / "scene", make_scene(6), "llff")
    refused(
        capsys,
        root,
        "plan",
        ["plan", scene, "--out", root / "p.png", "--plot", root / "p.png"],
        "--plot",
        "--out",
        "p.png",
        "are the same file",
        case="--plot same as --out [plan]",
    )


def test_manifest_is_never_the_output(root, capsys):
    need("evaluate")
    scene = write_posed(root / "scene", make_scene(6), "llff")
    (root / "lists").mkdir()
    (root / "lists" / "scenes.txt").write_text(f"{scene}\n")
    refused(
        capsys,
        root,
        "evaluate",
        ["evaluate", "--manifest", root / "lists" / "scenes.txt", "--out", root / "lists", "--quick"],
        "contains the manifest",
        case="--out holds the manifest [evaluate]",
    )


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> dict:
    """One tiny run (1 epoch on a 6-view 32x24 scene) and a plan, made once for the synthesize cases."""
    need("train", "synthesize")
    import contextlib
    import io

    from sparself.cli import main

    base = tmp_path_factory.mktemp("synth")
    scene = write_posed(base / "data" / "scene", make_scene(6), "llff")  # each in a folder of its own, so
    run_dir, plan = base / "runs" / "run", base / "plans" / "plan.json"  # that the parent holds one input
    plan.parent.mkdir()
    with contextlib.redirect_stderr(io.StringIO()) as err:
        assert main([str(a) for a in ["train", scene, "--out", run_dir, *TINY, "-q"]]) == 0, err.getvalue()
        assert main([str(a) for a in ["plan", scene, "--out", plan, "--n-mid", "2", "--n-extra", "0", "-q"]]) == 0, (
            err.getvalue()
        )
    assert (run_dir / MARKER).is_file()  # a run is a folder sparself wrote
    return {"root": base, "scene": scene, "run": run_dir, "plan": plan}


@pytest.mark.parametrize(
    "what, relation", [(w, r) for w in ("run", "scene") for r in RELATIONS] + [("plan", "same"), ("plan", "parent")]
)
def test_synthesize_never_writes_over_its_run_plan_or_scene(trained, capsys, monkeypatch, what, relation):
    """The run folder, the plan file and the run's source scene (found through the run, not given)."""
    root = trained["root"]
    link = root / "link"
    try:
        out = out_for(relation, trained[what], root, monkeypatch)
        name = {"run": "run", "scene": "scene", "plan": "plan.json"}[what]
        refused(
            capsys,
            root,
            "synthesize",
            ["synthesize", trained["run"], "--plan", trained["plan"], "--out", out],
            f"output {out}",
            name,
            case=f"--out {relation} {what} [synthesize]",
        )
    finally:
        link.unlink(missing_ok=True)


@pytest.mark.parametrize("cmd", ["poses", "train", "densify", "evaluate"])
def test_overwrite_replaces_only_what_sparself_wrote(root, capsys, cmd):
    """A non-empty folder without sparself's marker is never replaced, even with --overwrite."""
    need(cmd)
    inp = (
        write_photos(root / "photos", 3)[0].parent
        if cmd in ("poses", "densify")
        else write_posed(root / "scene", make_scene(6), "llff")
    )
    mine = root / "my_things"
    mine.mkdir()
    (mine / "thesis.tex").write_text("the only copy")
    extra = {"poses": [], "train": TINY, "densify": TINY_DENSIFY, "evaluate": ["--quick", "--recon", "mpi"]}[cmd]
    refused(
        capsys,
        root,
        cmd,
        [cmd, inp, "--out", mine, *extra],
        str(mine),
        "not a folder sparself wrote",
        "delete it yourself",
        case=f"--overwrite on a folder sparself did not write [{cmd}]",
    )


def test_overwrite_replaces_a_folder_sparself_wrote_or_an_empty_one(root, capsys):
    scene = write_posed(root / "scene", make_scene(6), "llff")
    (root / "out").mkdir()
    for _ in range(2):  # an empty folder, then the run just written there (it holds the marker)
        code, _, err = run(capsys, "train", scene, "--out", root / "out", *TINY, "--overwrite", "-q")
        assert code == 0, err
        assert (root / "out" / MARKER).is_file() and (root / "out" / "checkpoint.pt").is_file()
    assert sorted(p.name for p in root.iterdir()) == ["out", "scene"]


def test_synthesize_into_a_mount_point(trained, tmp_path, capsys, monkeypatch):
    """A mount point as --out (simulated: os.path.ismount says so and renaming it fails with EBUSY): the
    dense scene is written inside it, entry by entry, with no traceback and nothing left beside it."""
    import errno

    from sparself.capture.io import read_scene

    mnt = tmp_path / "mnt"
    mnt.mkdir()
    real_ismount, real_rename = os.path.ismount, os.rename

    def rename(src, dst):
        if mnt in (Path(src), Path(dst)):
            raise OSError(errno.EBUSY, os.strerror(errno.EBUSY))
        return real_rename(src, dst)

    monkeypatch.setattr(os.path, "ismount", lambda p: Path(p) == mnt or real_ismount(p))
    monkeypatch.setattr(os, "rename", rename)
    code, _, err = run(capsys, "synthesize", trained["run"], "--plan", trained["plan"], "--out", mnt, "-q")
    assert code == 0 and "Traceback" not in err, err
    assert len(read_scene(mnt)) == 6 + 2 and (mnt / MARKER).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mnt"]
    assert not [p for p in mnt.iterdir() if ".tmp-" in p.name]


def test_overwrite_that_cannot_delete_the_old_output_fails_up_front(trained, tmp_path, capsys, monkeypatch):
    """--overwrite of a dense scene sparself wrote, but whose images/ the user may not change (simulated:
    os.access says no, as it does for a read-only folder of another user): one line, before any work."""
    out = tmp_path / "dense"
    code, _, err = run(capsys, "synthesize", trained["run"], "--plan", trained["plan"], "--out", out, "-q")
    assert code == 0, err
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: Path(p) != out / "images" and real_access(p, mode, **kw))
    before = tree(tmp_path)
    code, _, err = run(
        capsys, "synthesize", trained["run"], "--plan", trained["plan"], "--out", out, "--overwrite", "-q"
    )
    one_error(
        code,
        err,
        "synthesize",
        str(out),
        "--overwrite cannot delete it",
        f"{out / 'images'}",
        case="--overwrite on a folder that cannot be deleted [synthesize]",
    )
    assert tree(tmp_path) == before


def test_train_overwrite_drops_the_old_checkpoint(trained, tmp_path, capsys, monkeypatch):
    """train --overwrite over a run, interrupted before its first checkpoint: the old run's checkpoint is
    gone (a later --resume must not continue it under the new config)."""
    import shutil

    import sparself.synthesis.train

    run_dir = tmp_path / "run"
    shutil.copytree(trained["run"], run_dir)
    assert (run_dir / "checkpoint.pt").is_file()

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(sparself.synthesis.train, "_fit", interrupted)
    argv = ["train", str(trained["scene"]), "--out", str(run_dir), *TINY, "--decoder", "fc", "--overwrite"]
    code, _, err = run(capsys, *argv)
    assert code == 130 and not (run_dir / "checkpoint.pt").exists(), err
    again = " ".join(a for a in argv if a != "--overwrite")
    assert (
        f"sparself train: interrupted; stopped before the first checkpoint; start again with: sparself {again} "
        "--resume" in err
    ), err


@pytest.mark.parametrize("relation", ["same", "parent", "child"])
def test_batch_never_writes_over_a_capture_or_its_manifest(root, capsys, monkeypatch, relation):
    need("batch")
    scene = write_posed(root / "caps" / "cap0", make_scene(6), "llff")
    (root / "lists").mkdir()
    manifest = root / "lists" / "m.txt"
    manifest.write_text(f"{scene}\n")
    out = out_for(relation, scene, root, monkeypatch)
    refused(
        capsys,
        root,
        "batch",
        ["batch", "densify", manifest, "--out", out, "--local"],
        f"output {out}",
        _how(relation),
        "capture",
        case=f"--out {relation} capture [batch]",
        overwrite=False,
    )
    refused(
        capsys,
        root,
        "batch",
        ["batch", "densify", manifest, "--out", manifest.parent, "--local"],
        "contains the manifest",
        case="--out holds the manifest [batch]",
        overwrite=False,
    )


@pytest.mark.parametrize("cmd", ["train", "densify", "plan"])
def test_a_scene_with_linked_photos_never_writes_into_the_photo_folder(root, capsys, cmd):
    """A scene written with --link-images holds links to the photos: the folder they point to is an input."""
    from planescene import on_disk
    from sparself.capture.io import write_scene

    photos = root / "p10"
    scene = on_disk(make_scene(6), photos)
    write_scene(scene, root / "lk", images="link")
    assert (root / "lk" / "images" / scene.frames[0].name).is_symlink()
    out = photos / "images" / ("plan.json" if cmd == "plan" else "here")
    line = refused(capsys, root, cmd, [cmd, root / "lk", "--out", out], "lies inside the scene's image folder")
    assert str(photos / "images") in line
