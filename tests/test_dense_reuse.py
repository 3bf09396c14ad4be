"""A densify output's trained run, reused for more views: ``sparself synthesize OUT/run --scene OUT/scene``
synthesizes from the dense scene's photos (never from its synthesized views, never from a held-out photo),
named and indexed as the run knew them, and gives the views that synthesizing from the original capture gives."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from conftest import make_tiny_cfg
from planescene import on_disk, small_plane_scene
from sparself.capture.io import read_scene, write_scene
from sparself.capture.scene import Frame
from sparself.evaluation.selfcheck import SelfCheckConfig
from sparself.pipeline import DensifyConfig, densify
from sparself.synthesis.plan import PlanConfig, make_plan, save_plan
from sparself.synthesis.run import load_run
from sparself.synthesis.synthesize import synthesize_plan
from test_bad_input import one_error, run


@pytest.fixture(scope="module")
def densified(tmp_path_factory) -> Path:
    """``sparself densify`` of a posed capture on disk (7 photos, COLMAP): ROOT/cap, ROOT/out/{scene,run,plan.json};
    the default test split holds 2 photos out of training and synthesis."""
    root = tmp_path_factory.mktemp("reuse")
    write_scene(on_disk(small_plane_scene(), root / "photos"), root / "cap", ("colmap",))
    cfg = DensifyConfig(
        train=make_tiny_cfg(epochs=1),
        plan=PlanConfig(n_mid=3, n_extra=2),
        check=SelfCheckConfig(recon="none"),
        downscaled=False,
    )
    densify(root / "cap", root / "out", cfg)
    return root


def _record(folder: Path) -> list[dict]:
    return json.loads((folder / "sparself.json").read_text())["frames"]


def _views(folder: Path) -> dict[str, tuple[np.ndarray, np.ndarray, dict]]:
    """Each synthesized view of a written dense scene by its planned name: image, mask, the photos it was made from."""
    return {
        fr["source_name"]: (
            np.asarray(Image.open(folder / "images" / fr["name"])),
            np.asarray(Image.open(folder / "masks" / (Path(fr["name"]).stem + ".png"))),
            fr["made_from"],
        )
        for fr in _record(folder)
        if fr["synthetic"]
    }


def _same_views(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b) and a
    for k in a:
        np.testing.assert_array_equal(a[k][0], b[k][0], err_msg=k)
        np.testing.assert_array_equal(a[k][1], b[k][1], err_msg=k)
        assert a[k][2] == b[k][2], k


def test_synthesize_from_the_dense_scene_gives_the_views_of_the_capture(densified, tmp_path, capsys):
    out = densified / "out"
    synthesize_plan(out / "run", out / "plan.json", tmp_path / "from_capture", downscaled=False)  # the run's scene
    code, _, err = run(
        capsys, "synthesize", out / "run", "--plan", out / "plan.json", "--scene", out / "scene",
        "--out", tmp_path / "from_dense", "--no-downscaled", "-q",
    )  # fmt: skip
    assert code == 0, err
    from_dense = _views(tmp_path / "from_dense")
    _same_views(_views(tmp_path / "from_capture"), from_dense)
    _same_views(_views(out / "scene"), from_dense)  # and the views densify wrote
    # made from the photos the run trained on, under their own names: never a synthesized view or a test photo
    dense = _record(out / "scene")
    test = json.loads((out / "scene" / "sparself.json").read_text())["split"]["test"]
    held = {fr["source_name"] for fr in dense if fr["name"] in test}
    trained = set(load_run(out / "run").meta.sources)
    assert len(held) == 2 and trained == {f.name for f in small_plane_scene().frames} - held
    fed = {n for v in from_dense.values() for n in v[2]["warped"] + v[2]["sequence"]}
    assert fed == trained
    photos = {fr["source_name"] for fr in _record(tmp_path / "from_dense") if not fr["synthetic"]}
    assert photos == trained


def test_a_plan_made_on_the_dense_scene_is_mapped_to_the_capture_scale(densified, tmp_path):
    """``sparself plan OUT/scene`` counts the synthesized frames; each planned view gets the index of its place in
    the capture, and the views are those of the same poses planned on the capture."""
    out = densified / "out"
    make_plan(out / "scene", tmp_path / "plan.json", PlanConfig(n_mid=4, n_extra=2))
    written = synthesize_plan(
        out / "run", tmp_path / "plan.json", tmp_path / "dense", scene_path=out / "scene", downscaled=False
    )
    new = [f for f in written.frames if f.synthetic]
    cap = read_scene(densified / "cap")
    x = cap.centers()[:, 0]  # the cameras move along x, one step per photo
    step = float(np.diff(x).mean())
    assert len(new) == 6 and np.allclose(np.diff(x), step)
    for f in new:
        assert f.index == pytest.approx((f.pose.center[0] - x[0]) / step, abs=1e-9), f.name
    names = {fr["name"]: fr["source_name"] for fr in _record(tmp_path / "dense")}
    planned = [
        Frame(names[f.name], f.pose, f.camera_id, f.index, synthetic=True) for f in sorted(new, key=lambda f: f.index)
    ]
    assert all(p.name == f"novel_{p.index:07.2f}.png" for p in planned)
    save_plan(tmp_path / "capture_plan.json", planned, scene=cap)
    synthesize_plan(out / "run", tmp_path / "capture_plan.json", tmp_path / "from_capture", downscaled=False)
    _same_views(_views(tmp_path / "from_capture"), _views(tmp_path / "dense"))


def test_without_scene_a_run_of_photos_uses_the_dense_scene_beside_it(densified, tmp_path):
    """A run densify trained on photos posed by SfM records the photo folder, which holds no poses: the dense
    scene beside the run does."""
    out = tmp_path / "out"
    shutil.copytree(densified / "out", out)
    ck = torch.load(out / "run" / "checkpoint.pt", weights_only=False)
    ck["meta"]["scene"] = str(densified / "photos" / "images")  # photos only
    torch.save(ck, out / "run" / "checkpoint.pt")
    synthesize_plan(out / "run", out / "plan.json", tmp_path / "again", downscaled=False)
    _same_views(_views(out / "scene"), _views(tmp_path / "again"))


@pytest.mark.parametrize(
    "edit, needles",
    [
        (lambda doc: doc["frames"].pop(3), ["sparself.json", "does not list the scene's image"]),
        (lambda doc: doc["frames"][0].pop("source_name"), ["sparself.json", "unreadable scene record"]),
        (lambda doc: doc.update(format="other"), ["sparself.json", "not a sparself scene record"]),
    ],
)
def test_a_dense_scene_whose_record_does_not_fit_is_refused_in_one_line(densified, tmp_path, capsys, edit, needles):
    scene = tmp_path / "scene"
    shutil.copytree(densified / "out" / "scene", scene)
    doc = json.loads((scene / "sparself.json").read_text())
    edit(doc)
    (scene / "sparself.json").write_text(json.dumps(doc))
    out = densified / "out"
    code, _, err = run(
        capsys, "synthesize", out / "run", "--plan", out / "plan.json", "--scene", scene, "--out", tmp_path / "x"
    )
    one_error(code, err, "synthesize", *needles)
    assert not (tmp_path / "x").exists()
