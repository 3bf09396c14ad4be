"""Dense-scene exports: synthesized frames marked and kept out of every loader's test split, SfM tracks,
images_N copies, upright images and sortable names; read back with the project's own readers."""

from __future__ import annotations

import itertools
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from planescene import camera_line, noise, on_disk
from sparself.capture.images import image_size_of
from sparself.capture.io import (
    DenseInfo,
    read_colmap,
    read_llff,
    read_nerfstudio,
    read_scene,
    write_colmap,
    write_scene,
)
from sparself.capture.io.dense import EVERY, downscaled_size, n_test_positions, safe_order
from sparself.capture.scene import Frame, Scene
from sparself.core.geometry import Pose, interpolate_pose, rotmat_to_quat

W, H, FOCAL = 27, 18, 24.0  # odd sizes: w // f and round(w / f) differ


def _photos(folder: Path, n: int, ext: str = ".png") -> Scene:
    """n photos of random pixels on disk (000.png, ...), cameras on the x axis looking at 50 sparse points."""
    scene = on_disk(
        camera_line(
            [0.1 * i for i in range(n)],
            (W, H),
            FOCAL,
            lambda pose, cam, i: noise(H, W, i),
            bounds=(1.0, 5.0),
            name=lambda i: f"{i:03d}{ext}",
        ),
        folder,
    )
    rng = np.random.default_rng(0)
    scene.points = np.column_stack(
        [rng.uniform(-0.3, 0.1 * n + 0.3, 50), rng.uniform(-0.5, 0.5, 50), rng.uniform(2.0, 4.0, 50)]
    )
    return scene


# ---- the position rule (pure) --------------------------------------------------------------------


def _check_order(flags: list[bool], every: int = EVERY) -> None:
    n, order = len(flags), safe_order(flags, every)
    n_real = flags.count(False)
    if n_real < n_test_positions(n, every):
        assert order is None
        return
    assert sorted(order) == list(range(n))
    written = [flags[i] for i in order]
    assert not any(written[p] for p in range(0, n, every)), (flags, order)
    # each kind keeps its own (index) order
    assert [i for i in order if flags[i]] == [i for i in range(n) if flags[i]]
    assert [i for i in order if not flags[i]] == [i for i in range(n) if not flags[i]]
    if not any(flags[p] for p in range(0, n, every)):
        assert order == list(range(n))  # already safe: index order untouched


def test_safe_order_every_pattern_up_to_14_views():
    for n in range(1, 15):
        for flags in itertools.product([False, True], repeat=n):
            _check_order(list(flags))


def test_safe_order_3_to_500_views_any_number_synthesized():
    """Every view count 3..500 and, for each, synthesized counts from none to all (every count near the
    feasibility limit, a spread elsewhere), in random and planner-like positions."""
    rng = np.random.default_rng(0)
    for n in range(3, 501):
        limit = n - n_test_positions(n)  # most synthesized frames that can be served
        counts = set(range(0, n + 1, max(1, n // 12))) | {1, 2, limit - 1, limit, limit + 1, n}
        for s in sorted(c for c in counts if 0 <= c <= n):
            flags = np.zeros(n, bool)
            flags[rng.choice(n, s, replace=False)] = True
            _check_order(flags.tolist())
            _check_order([True] * s + [False] * (n - s))  # extrapolations first
    for real in range(3, 501):  # the planner: a midpoint in every gap, two extrapolations before, one after
        flags = [True, True] + [x for k in range(real) for x in ([False, True] if k < real - 1 else [False])] + [True]
        _check_order(flags)


def test_downscaled_size_is_floor():
    assert downscaled_size(1001, 667, 8) == (125, 83)
    assert downscaled_size(1006, 670, 4) == (251, 167)  # round() would give 252 and 168
    assert downscaled_size(5, 3, 8) == (1, 1)


# ---- a written dense scene ---------------------------------------------------------------------------


def _dense_scene(folder: Path, n: int = 10, ext: str = ".png") -> Scene:
    """n real views + synthesized ones at -0.4, -0.2 (before the start), midpoints and one past the end."""
    scene = _photos(folder, n, ext)
    rng = np.random.default_rng(1)
    targets = []
    for idx in (-0.4, -0.2, 0.5, 3.5, 5.5, 7.5, n - 1 + 0.2):
        a = int(np.clip(np.floor(idx), 0, n - 2))
        t = idx - a
        pose = interpolate_pose(scene.frames[a].pose, scene.frames[a + 1].pose, t)
        targets.append(
            Frame(
                name=f"novel_{idx:07.2f}.png",
                pose=pose,
                index=idx,
                synthetic=True,
                image=rng.random((H, W, 3)).astype(np.float32),
            )
        )
    return replace(scene, frames=sorted(scene.frames + targets, key=lambda f: f.index))


@pytest.fixture
def written(tmp_path):
    scene = _dense_scene(tmp_path / "src", ext=".jpg")
    out = write_scene(scene, tmp_path / "out", dense=DenseInfo(run="run", plan="plan.json"))
    return scene, out, tmp_path / "out"


def test_split_lists_agree_with_synthetic_flags(written):
    scene, out, folder = written
    tj = json.loads((folder / "transforms.json").read_text())
    flag = {Path(fr["file_path"]).name: fr["synthetic"] for fr in tj["frames"]}
    assert sum(flag.values()) == 7 and len(flag) == 17
    sj = json.loads((folder / "sparself.json").read_text())
    assert {fr["name"]: fr["synthetic"] for fr in sj["frames"]} == flag
    assert sj["run"] == "run" and sj["plan"] == "plan.json" and sj["version"] == 1
    split = {k: [Path(p).name for p in tj[f"{k}_filenames"]] for k in ("train", "val", "test")}
    assert set(split["train"]) | set(split["test"]) == set(flag) and not set(split["train"]) & set(split["test"])
    assert split["val"] == split["test"] and not any(flag[n] for n in split["test"])
    # every 8th of ALL names in sorted order, as gsplat, NeRF/LLFF, 3DGS and nerfstudio pick them: real photos
    assert split["test"] == sorted(flag)[::8] and len(split["test"]) == 3
    assert sj["split"]["test"] == split["test"] and "every 8th image of all" in sj["split"]["rule"]
    for k, fname in (("train", "train_list.txt"), ("val", "val_list.txt"), ("test", "test_list.txt")):
        assert (folder / fname).read_text().split() == split[k]
    assert (folder / "sparse" / "0" / "test.txt").read_text().split() == split["test"]
    # the project's readers: flags come back from transforms.json and from sparself.json (COLMAP, LLFF)
    for back in (
        read_nerfstudio(folder),
        read_scene(folder),
        read_scene(folder / "sparse" / "0"),
        read_scene(folder / "poses_bounds.npy"),
    ):
        assert {f.name: f.synthetic for f in back.frames} == flag


def test_sorted_names_keep_synthesized_frames_off_every_8th_position(written):
    scene, out, folder = written
    names = sorted(p.name for p in (folder / "images").iterdir())
    assert names == [f.name for f in out.frames]  # sorted order = written order = COLMAP image ids
    synth = {f.name for f in out.frames if f.synthetic}
    assert not any(names[p] in synth for p in range(0, len(names), EVERY))
    # index order except where a synthesized frame had to wait: -0.4 and -0.2 come after real view 0 and,
    # of 17 views, the last position (16) must hold real view 9, so 9.2 goes before it
    idx = [f.index for f in out.frames]
    assert idx == [0, -0.4, -0.2, 0.5, 1, 2, 3, 3.5, 4, 5, 5.5, 6, 7, 7.5, 8, 9.2, 9]
    assert [f.synthetic for f in out.frames] == [f.synthetic for f in sorted(out.frames, key=lambda f: f.name)]
    # LLFF rows follow the same sorted order
    llff = read_llff(folder)
    assert [f.name for f in llff.frames] == names


def test_synthesized_views_in_the_photos_format_and_all_upright(written):
    scene, out, folder = written
    for f in out.frames:
        assert f.name.endswith(".jpg")
        with Image.open(folder / "images" / f.name) as im:
            assert im.format == "JPEG" and im.getexif().get(0x0112, 1) == 1
            assert im.size == (out.camera(0).width, out.camera(0).height)


def test_images_n_sizes_and_cameras(written):
    scene, out, folder = written
    names = sorted(p.name for p in (folder / "images").iterdir())
    for k in (2, 4, 8):
        d = folder / f"images_{k}"
        assert sorted(p.name for p in d.iterdir()) == names
        for n in names:
            assert image_size_of(d / n) == downscaled_size(W, H, k)
        small = read_llff(folder, images=d)  # our LLFF reader scales the focal to the files, as NeRF's does
        cam = small.camera(0)
        assert (cam.width, cam.height) == downscaled_size(W, H, k)
        assert cam.fx == pytest.approx(FOCAL * cam.width / W)


def test_every_image_has_observations_that_reproject_within_a_pixel(written):
    import pycolmap

    scene, out, folder = written
    rec = pycolmap.Reconstruction(str(folder / "sparse" / "0"))
    back = read_colmap(folder)
    K = back.camera(0).K
    assert rec.num_images() == 17
    for im in rec.images.values():
        obs = im.get_observation_points2D()
        assert len(obs) >= 1, im.name
        pose = back.frames[[f.name for f in back.frames].index(im.name)].pose
        for p in obs:
            X = pose.R @ rec.points3D[p.point3D_id].xyz + pose.tvec
            uv = (K @ X)[:2] / X[2]
            assert np.linalg.norm(uv - p.xy) < 1.0, im.name


def _model_with_tracks(folder: Path, offset: float) -> Scene:
    """A COLMAP model whose real observations sit ``offset`` px from the exact projections."""
    import pycolmap

    scene = _photos(folder, 9)
    write_colmap(scene, folder / "sparse" / "0")
    rec = pycolmap.Reconstruction(str(folder / "sparse" / "0"))
    kept = []
    for im in rec.images.values():
        assert len(im.get_observation_points2D()) > 0  # projected when the scene had no tracks
        for p2 in im.points2D:
            p2.xy = p2.xy + offset
        kept.append(im.name)
    rec.write_binary(str(folder / "sparse" / "0"))
    return read_colmap(folder)


def test_real_sfm_tracks_are_kept_and_synthesized_views_get_projected_ones(tmp_path):
    import pycolmap

    src = _model_with_tracks(tmp_path / "src", offset=0.25)
    assert len(src.observations) == 9
    n_src = {n: len(o.point) for n, o in src.observations.items()}
    mid = interpolate_pose(src.frames[3].pose, src.frames[4].pose, 0.5)
    dense = replace(
        src,
        frames=src.frames
        + [Frame(name="novel_0003.50.png", pose=mid, index=3.5, synthetic=True, image=np.zeros((H, W, 3), np.float32))],
    )
    dense.frames.sort(key=lambda f: f.index)
    out = write_scene(dense, tmp_path / "out", dense=DenseInfo(downscale=False))
    assert not (tmp_path / "out" / "images_2").exists()
    rec = pycolmap.Reconstruction(str(tmp_path / "out" / "sparse" / "0"))
    K = out.camera(0).K
    by_name = {f.name: f for f in out.frames}
    sj = json.loads((tmp_path / "out" / "sparself.json").read_text())
    source = {fr["name"]: fr["source_name"] for fr in sj["frames"]}
    for im in rec.images.values():
        f = by_name[im.name]
        obs = im.get_observation_points2D()
        err = [
            np.linalg.norm(
                (K @ (f.pose.R @ rec.points3D[p.point3D_id].xyz + f.pose.tvec))[:2]
                / (f.pose.R @ rec.points3D[p.point3D_id].xyz + f.pose.tvec)[2]
                - p.xy
            )
            for p in obs
        ]
        assert len(obs) >= 1 and max(err) < 1.0
        if f.synthetic:
            assert max(err) < 1e-6
        else:  # the SfM observations, offset and all
            assert len(obs) == n_src[source[im.name]] and np.allclose(err, 0.25 * np.sqrt(2), atol=1e-6)


def test_tracks_scale_with_a_resized_scene(tmp_path):
    src = _model_with_tracks(tmp_path / "src", offset=0.0)
    small = src.resized(12)  # 27x18 -> 12x8
    from sparself.capture.io.colmap import reconstruction_from_scene

    rec = reconstruction_from_scene(small)
    f = small.frames[0]
    K = small.camera(0).K
    im = next(i for i in rec.images.values() if i.name == f.name)
    for p in im.get_observation_points2D():
        X = f.pose.R @ rec.points3D[p.point3D_id].xyz + f.pose.tvec
        assert np.linalg.norm((K @ X)[:2] / X[2] - p.xy) < 1e-6


def test_exif_rotated_photo_written_upright_without_flag(tmp_path):
    """A phone photo stored H x W with orientation 6 (rotate 90): its camera says W x H upright."""
    scene = _dense_scene(tmp_path / "src", n=4)
    real = next(f for f in scene.frames if not f.synthetic)
    raw = (np.random.default_rng(0).random((W, H, 3)) * 255).astype(np.uint8)  # H wide, W high
    exif = Image.Exif()
    exif[0x0112] = 6
    p = real.path.with_suffix(".jpg")
    Image.fromarray(raw).save(p, exif=exif, quality=98)
    real.path.unlink()
    real.path, real.name = p, p.name
    assert image_size_of(p) == (W, H)
    out = write_scene(scene, tmp_path / "out")
    f = next(f for f in out.frames if not f.synthetic and f.name.endswith("_000.jpg"))
    with Image.open(f.path) as im:
        assert im.size == (W, H) and im.getexif().get(0x0112, 1) == 1
    for k in (2, 4, 8):
        assert image_size_of(tmp_path / "out" / f"images_{k}" / f.name) == downscaled_size(W, H, k)


def test_user_holdout_goes_to_val_and_test(tmp_path):
    scene = _dense_scene(tmp_path / "src")
    write_scene(scene, tmp_path / "out", dense=DenseInfo(holdout=("003.png", "006.png"), downscale=False))
    tj = json.loads((tmp_path / "out" / "transforms.json").read_text())
    assert [Path(p).name.split("_", 1)[1] for p in tj["test_filenames"]] == ["003.png", "006.png"]
    with pytest.raises(ValueError, match="holdout"):
        write_scene(scene, tmp_path / "out2", dense=DenseInfo(holdout=("novel_0000.50.png",)))


def test_too_few_real_views_warns_and_keeps_index_order(tmp_path, caplog):
    scene = _photos(tmp_path / "src", 3)
    extra = [
        Frame(
            name=f"novel_{i:07.2f}.png",
            pose=scene.frames[0].pose,
            index=0.05 * (i + 1),
            synthetic=True,
            image=np.zeros((H, W, 3), np.float32),
        )
        for i in range(19)
    ]  # 22 views need 3 real at 0, 8, 16
    extra += [
        Frame(
            name="novel_late.png",
            pose=scene.frames[0].pose,
            index=5.0,
            synthetic=True,
            image=np.zeros((H, W, 3), np.float32),
        )
    ]  # 23 views: 0, 8, 16 -> still 3
    dense = replace(scene, frames=sorted(scene.frames + extra, key=lambda f: f.index))
    out = write_scene(dense, tmp_path / "ok", dense=DenseInfo(downscale=False))
    assert not any(out.frames[p].synthetic for p in (0, 8, 16))
    more = dense.frames + [replace(extra[0], name=f"novel_x{i}.png", index=6.0 + i) for i in range(2)]  # 25: 4 tests
    out = write_scene(replace(dense, frames=more), tmp_path / "bad", dense=DenseInfo(downscale=False))
    assert "too few real photos" in caplog.text
    assert json.loads((tmp_path / "bad" / "sparself.json").read_text())["position_based_test_sets_are_real"] is False


def test_scene_without_synthesized_frames_keeps_its_names(tmp_path):
    scene = _photos(tmp_path / "src", 4)
    out = write_scene(scene, tmp_path / "out")
    assert [f.name for f in out.frames] == ["000.png", "001.png", "002.png", "003.png"]
    assert not (tmp_path / "out" / "sparself.json").exists()
    assert "train_filenames" not in json.loads((tmp_path / "out" / "transforms.json").read_text())


def test_a_view_that_sees_no_point_gets_one_on_its_axis(tmp_path):
    """A synthesized view turned away from every sparse point still has an observation (gsplat's depth
    loss looks each image up in its tracks): a new point on its optical axis, seen at the principal point."""
    import pycolmap

    scene = _dense_scene(tmp_path / "src", n=9)
    away = next(f for f in scene.frames if f.synthetic)
    R = away.pose.R
    flip = np.diag([-1.0, 1.0, -1.0])  # turn 180 degrees about the camera's y axis: the points are behind it
    center = away.pose.center
    away.pose = Pose(rotmat_to_quat(flip @ R), -(flip @ R) @ center)
    out = write_scene(scene, tmp_path / "out", dense=DenseInfo(downscale=False))
    rec = pycolmap.Reconstruction(str(tmp_path / "out" / "sparse" / "0"))
    assert rec.num_points3D() == 51
    f = next(f for f in out.frames if f.synthetic and f.index == away.index)
    im = next(i for i in rec.images.values() if i.name == f.name)
    obs = im.get_observation_points2D()
    assert len(obs) == 1 and np.allclose(obs[0].xy, [out.camera(0).cx, out.camera(0).cy])
    X = f.pose.R @ rec.points3D[obs[0].point3D_id].xyz + f.pose.tvec
    assert X[2] > 0 and np.allclose(X[:2], 0, atol=1e-9)
    assert all(i.num_points3D >= 1 for i in rec.images.values())


@pytest.mark.parametrize("binary", [False, True])
def test_transforms_json_scene_brings_its_point_cloud_and_gets_tracks(tmp_path, binary):
    """A transforms.json input with a PLY point cloud (ASCII as we write it, or binary as nerfstudio's
    exports are): the points are read, and every written image observes some of them."""
    import pycolmap

    from sparself.capture.io import write_nerfstudio

    scene = _dense_scene(tmp_path / "src", n=9)
    real = replace(scene, frames=[f for f in scene.frames if not f.synthetic])
    write_nerfstudio(real, tmp_path / "src")
    ply = tmp_path / "src" / "sparse_pc.ply"
    if binary:
        pts = np.asarray(scene.points, np.float32)
        head = (
            f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\nproperty float x\n"
            "property float y\nproperty float z\nproperty uchar red\nproperty uchar green\n"
            "property uchar blue\nend_header\n"
        ).encode()
        rec = np.zeros(len(pts), dtype=[(c, "<f4") for c in "xyz"] + [(c, "u1") for c in "rgb"])
        rec["x"], rec["y"], rec["z"], rec["r"] = pts[:, 0], pts[:, 1], pts[:, 2], 200
        ply.write_bytes(head + rec.tobytes())
    back = read_nerfstudio(tmp_path / "src")
    np.testing.assert_allclose(back.points, scene.points, atol=1e-6)
    if binary:
        assert np.all(back.point_colors[:, 0] == 200)
    dense = replace(back, frames=sorted(back.frames + [f for f in scene.frames if f.synthetic], key=lambda f: f.index))
    write_scene(dense, tmp_path / "out", dense=DenseInfo(downscale=False))
    rec = pycolmap.Reconstruction(str(tmp_path / "out" / "sparse" / "0"))
    assert rec.num_images() == 16 and all(im.num_points3D >= 1 for im in rec.images.values())
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n")
    assert read_nerfstudio(tmp_path / "src").points is None  # unreadable cloud: a warning, not a failure


def test_a_dense_scene_written_again_keeps_one_rank_prefix(written, tmp_path):
    scene, out, folder = written
    again = read_scene(folder)
    assert sum(f.synthetic for f in again.frames) == 7
    out2 = write_scene(again, tmp_path / "again", dense=DenseInfo(downscale=False))
    assert [f.name for f in out2.frames] == [f.name for f in out.frames]


def test_densify_writes_the_dense_scene_with_its_split_and_provenance(tmp_path, small_scene, tiny_cfg):
    """The pipeline end to end on the small plane scene (7 views, 40 x 28): the user's held-out view is
    val/test, synthesized views are train only, sparself.json names the run and plan beside the scene."""
    from sparself.evaluation.selfcheck import SelfCheckConfig
    from sparself.pipeline import DensifyConfig, densify
    from sparself.synthesis.plan import PlanConfig

    cfg = DensifyConfig(
        train=tiny_cfg(epochs=1, holdout=(3,)), plan=PlanConfig(n_mid=3, n_extra=2), check=SelfCheckConfig(recon="none")
    )
    densify(small_scene, tmp_path / "out", cfg)
    folder = tmp_path / "out" / "scene"
    sj = json.loads((folder / "sparself.json").read_text())
    assert sj["run"] == "../run" and sj["plan"] == "../plan.json"
    assert (folder / sj["run"] / "checkpoint.pt").is_file() and (folder / sj["plan"]).is_file()
    src = {fr["name"]: fr["source_name"] for fr in sj["frames"]}
    assert [src[n] for n in sj["split"]["test"]] == ["f03.png"]
    assert sum(fr["synthetic"] for fr in sj["frames"]) == 5 and len(sj["frames"]) == 12
    assert not any(fr["synthetic"] for fr in sj["frames"] if fr["name"] in sj["split"]["test"])
    names = sorted(p.name for p in (folder / "images").iterdir())
    assert names == [fr["name"] for fr in sj["frames"]] and not src[names[8]].startswith("novel_")
    for k in (2, 4, 8):
        assert sorted(p.name for p in (folder / f"images_{k}").iterdir()) == names
    _check_masks(folder, sj)


@pytest.mark.parametrize("test_split", [True, False])
def test_test_photos_feed_neither_training_nor_synthesis(tmp_path, small_scene, tiny_cfg, test_split):
    """By default the photos position-based loaders test (every 8th of all written images) are the test split
    and are kept out of training and of every synthesized view (sparself.json names the photos that fed each
    one); --no-test-split uses every photo and writes no test split."""
    from sparself.evaluation.selfcheck import SelfCheckConfig
    from sparself.pipeline import DensifyConfig, densify
    from sparself.synthesis.plan import PlanConfig
    from sparself.synthesis.run import load_run

    check = SelfCheckConfig(recon="none")
    cfg = DensifyConfig(
        train=tiny_cfg(epochs=1), plan=PlanConfig(n_mid=3, n_extra=2), test_split=test_split, check=check
    )
    densify(small_scene, tmp_path / "out", cfg)
    folder = tmp_path / "out" / "scene"
    sj = json.loads((folder / "sparself.json").read_text())
    src = {fr["name"]: fr["source_name"] for fr in sj["frames"]}
    test = [src[n] for n in sj["split"]["test"]]
    trained = set(load_run(tmp_path / "out" / "run").meta.sources)
    fed = {n for fr in sj["frames"] if fr["synthetic"] for n in fr["made_from"]["warped"] + fr["made_from"]["sequence"]}
    assert all(len(fr["made_from"]["warped"]) >= 2 for fr in sj["frames"] if fr["synthetic"])
    if test_split:
        names = sorted(p.name for p in (folder / "images").iterdir())
        assert sj["split"]["test"] == names[::8] and (folder / "test_list.txt").read_text().split() == names[::8]
        assert len(test) == 2 and not set(test) & trained and not set(test) & fed
        assert trained | set(test) == {f.name for f in small_scene.frames}
    else:
        assert test == [] and "none" in sj["split"]["rule"] and not (folder / "test_list.txt").exists()
        assert trained == {f.name for f in small_scene.frames} and fed == trained
        assert "test_filenames" not in json.loads((folder / "transforms.json").read_text())


def _check_masks(folder: Path, sj: dict) -> None:
    """Confidence masks: one single-channel PNG per image (and per images_N copy) of the same size,
    transforms.json's mask_path names it, real photos are fully valid, synthesized ones hold values."""
    from PIL import Image

    frames = json.loads((folder / "transforms.json").read_text())["frames"]
    assert len(frames) == len(sj["frames"])
    synthetic = {fr["name"]: fr["synthetic"] for fr in sj["frames"]}
    for fr in frames:
        name = Path(fr["file_path"]).name
        assert fr["mask_path"] == f"masks/{Path(name).stem}.png"
        for sub in ("", "_2", "_4", "_8"):
            img = Image.open(folder / f"images{sub}" / name)
            mask = Image.open(folder / f"masks{sub}" / Path(fr["mask_path"]).name)
            assert mask.mode == "L" and mask.size == img.size
        m = np.asarray(Image.open(folder / fr["mask_path"]))
        assert (m == 255).all() if not synthetic[name] else (m.min() < 255 and m.max() > 0)


def test_no_downscaled_reaches_densify_and_synthesize(monkeypatch):
    """--no-downscaled on both commands that write a dense scene; the copies are on by default."""
    from sparself import cli, pipeline
    from sparself.capture.scene import Scene
    from sparself.synthesis import synthesize

    seen = {}

    def keep(key, value):  # -> an empty scene, for the commands' summary lines
        seen.setdefault(key, value)
        return Scene({}, [])

    monkeypatch.setattr(pipeline, "densify", lambda photos, out, cfg, resume=False: keep("densify", cfg.downscaled))
    monkeypatch.setattr(synthesize, "synthesize_plan", lambda *a, downscaled, **k: keep("synth", downscaled))
    for flag, want in (([], True), (["--no-downscaled"], False)):
        seen.clear()
        assert cli.main(["densify", "p", "--out", "o", "-q", *flag]) == 0
        assert cli.main(["synthesize", "r", "--plan", "x.json", "--out", "o", "-q", *flag]) == 0
        assert seen == {"densify": want, "synth": want}
    assert pipeline.DensifyConfig().downscaled is True
