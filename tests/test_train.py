"""Leakage-free training, resume, determinism, synthesis and the densify pipeline on tiny scenes."""

from __future__ import annotations

import csv
import dataclasses
import json
import logging

import numpy as np
import pytest
import torch

from planescene import SF, SH, SW
from planescene import small_plane_scene as plane_scene
from planescene import small_view as render_plane
from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.errors import ConfigError, InputError, OutputError
from sparself.core.geometry import Pose
from sparself.synthesis.run import load_run
from sparself.synthesis.synthesize import densify_scene, synthesize
from sparself.synthesis.train import predict_leave_one_out, train
from sparself.synthesis.train_config import TrainConfig

W, H, F = SW, SH, SF


def _state(run):
    return {k: v.clone() for k, v in run.model.state_dict().items()}


@pytest.mark.parametrize(
    "decoder",
    [{"decoder": "sweep"}, {"decoder": "fc"}, {"decoder": "sweep", "fallback": "flow"}],
    ids=["sweep", "fc", "sweep-flow"],
)
def test_target_pixels_never_reach_its_own_prediction(tmp_path, decoder, tiny_cfg):
    scene = plane_scene()
    run = train(scene, tmp_path / "run", tiny_cfg(epochs=1, **decoder), progress=False)
    base = predict_leave_one_out(run, scene, [3])
    changed = dataclasses.replace(scene, frames=list(scene.frames))
    changed.frames[3] = dataclasses.replace(
        scene.frames[3], image=np.random.default_rng(1).random((H, W, 3), np.float32)
    )
    assert np.array_equal(predict_leave_one_out(run, changed, [3]), base)
    # the test can fail: the frame before it is a source, and changing it does change the prediction
    changed.frames[2] = changed.frames[3]
    changed.frames[2] = dataclasses.replace(scene.frames[2], image=np.zeros((H, W, 3), np.float32))
    assert not np.allclose(predict_leave_one_out(run, changed, [3]), base)


def test_holdout_frames_are_never_opened(tmp_path, tiny_cfg):
    scene = plane_scene()
    (tmp_path / "images").mkdir()  # an image folder of its own: a run may not be written inside one
    broken = tmp_path / "images" / "held_out.png"
    broken.write_bytes(b"")  # opening it would raise InputError
    scene.frames[4] = dataclasses.replace(scene.frames[4], image=None, path=broken)
    run = train(scene, tmp_path / "run", tiny_cfg(epochs=1, holdout=(4,)), progress=False)
    assert "f04.png" not in run.meta.sources and len(run.meta.sources) == 6
    with pytest.raises(ConfigError, match="outside"):
        train(scene, tmp_path / "run2", tiny_cfg(epochs=1, holdout=(9,)), progress=False)


def test_a_tiny_sequence_is_fitted(tmp_path, tiny_cfg):
    scene = plane_scene(5)
    train(scene, tmp_path / "run", tiny_cfg(decoder="fc", epochs=30, batch_size=5, checkpoint_every=10), progress=False)
    with open(tmp_path / "run" / "train_log.csv") as f:
        loss = [float(r["loss"]) for r in csv.DictReader(f)]
    assert len(loss) == 30
    assert loss[-1] < 0.2 * loss[0]


def test_resume_ends_with_the_same_weights_as_an_uninterrupted_run(tmp_path, caplog, tiny_cfg):
    scene = plane_scene()
    with caplog.at_level(logging.INFO, logger="sparself"):
        full = train(scene, tmp_path / "full", tiny_cfg(epochs=4), progress=False)
    # without a progress bar, each checkpoint is logged
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("train: epoch")]
    assert said and said[-1].startswith("train: epoch 4/4, loss ")
    train(scene, tmp_path / "part", tiny_cfg(epochs=2), progress=False)
    resumed = train(scene, tmp_path / "part", tiny_cfg(epochs=4), resume=True, progress=False)
    a, b = _state(full), _state(resumed)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    with open(tmp_path / "part" / "train_log.csv") as f:
        assert [int(r["epoch"]) for r in csv.DictReader(f)] == [1, 2, 3, 4]
    saved = json.loads((tmp_path / "part" / "config.json").read_text())
    assert saved["epochs"] == 4 and saved["decoder"] == "sweep"


def test_resume_with_another_config_is_a_clear_error(tmp_path, tiny_cfg):
    scene = plane_scene()
    train(scene, tmp_path / "run", tiny_cfg(epochs=1), progress=False)
    with pytest.raises(ConfigError, match="decoder='sweep'.*asked: 'fc'"):
        train(scene, tmp_path / "run", tiny_cfg(epochs=2, decoder="fc"), resume=True, progress=False)
    with pytest.raises(ConfigError, match="channels=4"):
        train(scene, tmp_path / "run", tiny_cfg(epochs=2, channels=6), resume=True, progress=False)
    # a checkpoint whose tensors do not fit the model it claims: ConfigError, not a shape traceback
    ck = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)
    ck["model"]["decoder.conv_in.weight"] = torch.zeros(2, 4, 3, 3, 3)
    torch.save(ck, tmp_path / "run" / "checkpoint.pt")
    with pytest.raises(ConfigError, match="does not fit"):
        load_run(tmp_path / "run")
    with pytest.raises(InputError, match="no checkpoint"):
        load_run(tmp_path / "nothing")


def test_same_seed_same_images_and_novel_views_land_between_sources(tmp_path, tiny_cfg):
    scene = plane_scene()
    targets = [
        Frame("mid", Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([2.5 * 0.08, 0, 0])), 1, 2.5),
        Frame("after", Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([6.2 * 0.08, 0, 0])), 1, 6.2),
    ]
    r1 = train(scene, tmp_path / "a", tiny_cfg(epochs=2), progress=False)
    train(scene, tmp_path / "b", tiny_cfg(epochs=2), progress=False)
    out1, out2 = synthesize(r1, scene, targets), synthesize(tmp_path / "b", scene, targets)
    assert out1.shape == (2, H, W, 3) and out1.dtype == np.float32
    assert np.array_equal(out1, out2)
    assert np.all(out1 >= 0) and np.all(out1 <= 1)
    # a fronto-parallel plane with correct geometry: far better than a constant image
    gt = render_plane(2.5 * 0.08)
    mse = float(np.mean((out1[0, 4:-4, 4:-4] - gt[4:-4, 4:-4]) ** 2))
    assert mse < 0.25 * float(np.var(gt))
    dense = densify_scene(scene, targets, out1)
    assert [f.index for f in dense.frames] == [0, 1, 2, 2.5, 3, 4, 5, 6, 6.2]
    assert sum(f.synthetic for f in dense.frames) == 2
    assert np.array_equal(dense.frames[3].image, out1[0]) and dense.frames[3].synthetic


def test_densify_end_to_end(tmp_path, tiny_cfg):
    from sparself.capture import io as sio
    from sparself.evaluation.selfcheck import SelfCheckConfig
    from sparself.pipeline import DensifyConfig, densify
    from sparself.synthesis.plan import PlanConfig

    scene = plane_scene(7)
    src = tmp_path / "capture"
    sio.write_scene(scene, src)
    out = tmp_path / "dense"
    check = SelfCheckConfig(recon="none")
    cfg = DensifyConfig(train=tiny_cfg(epochs=2), plan=PlanConfig(n_mid=3, n_extra=2), check=check)
    dense = densify(src, out, cfg)
    assert len(dense) == 12 and sum(f.synthetic for f in dense.frames) == 5
    back = sio.read_scene(out / "scene")
    assert len(back) == 12
    assert (out / "scene" / "transforms.json").is_file() and (out / "scene" / "poses_bounds.npy").is_file()
    assert (out / "scene" / "sparse" / "0").is_dir() and (out / "run" / "checkpoint.pt").is_file()
    from sparself.synthesis.plan_files import load_plan

    planned = load_plan(out / "plan.json", back, check_source=False)  # back: sources + synthesized
    synth = {f.name: f for f in dense.frames if f.synthetic}
    assert sorted(f.name for f in planned) == sorted(synth)
    for f in planned:  # the written plan holds exactly the poses that were synthesized
        np.testing.assert_allclose(f.pose.w2c(), synth[f.name].pose.w2c(), atol=1e-9)
    assert (out / "cameras.png").stat().st_size > 1000
    with pytest.raises(OutputError):
        densify(src, out, cfg)  # refuses a non-empty output folder


def test_cli_train_then_synthesize_a_plan(tmp_path, capsys):
    from sparself.capture import io as sio
    from sparself.cli import main

    sio.write_scene(plane_scene(6), tmp_path / "capture")
    run = tmp_path / "run"
    assert (
        main(
            [
                "train",
                str(tmp_path / "capture"),
                "--out",
                str(run),
                "--epochs",
                "2",
                "--size",
                "40",
                "--crop",
                "16",
                "--backbone-size",
                "32",
                "--holdout",
                "2",
                "-q",
            ]
        )
        == 0
    )
    assert json.loads((run / "config.json").read_text())["holdout"] == [2]
    assert (
        main(
            [
                "plan",
                str(tmp_path / "capture"),
                "--out",
                str(tmp_path / "plan.json"),
                "--n-mid",
                "2",
                "--n-extra",
                "0",
                "-q",
            ]
        )
        == 0
    )
    assert (
        main(["synthesize", str(run), "--plan", str(tmp_path / "plan.json"), "--out", str(tmp_path / "dense"), "-q"])
        == 0
    )
    dense = sio.read_scene(tmp_path / "dense")
    assert len(dense) == 5 + 2  # the held-out frame is not a source
    assert (
        main(
            [
                "train",
                str(tmp_path / "capture"),
                "--out",
                str(run),
                "--epochs",
                "3",
                "--decoder",
                "fc",
                "--resume",
                "-q",
            ]
        )
        == 2
    )
    assert "different config" in capsys.readouterr().err


def test_sweep_planes_surround_the_object_of_a_ring_capture():
    from sparself.core.geometry import rotmat_to_quat
    from sparself.synthesis.train_config import sweep_depth_bounds

    frames = []
    for k in range(8):
        a = 2 * np.pi * k / 8
        c = 2.0 * np.array([np.cos(a), 0.0, np.sin(a)])
        z = -c / np.linalg.norm(c)  # looks at the origin
        x = np.cross([0.0, 1.0, 0.0], z)
        R = np.stack([x, np.cross(z, x), z])  # world-to-camera rows: camera axes in world
        frames.append(Frame(f"r{k}", Pose.from_center(rotmat_to_quat(R), c), 1, float(k)))
    ring = Scene({1: Camera.pinhole(W, H, F)}, frames)
    near, far = sweep_depth_bounds(ring)
    assert np.isclose(near, 1.0) and np.isclose(far, 3.0)
    # "object": every camera is 2 from the point; half the long side's field of view has tan W / (2f)
    assert np.allclose(sweep_depth_bounds(ring, "object"), (1.0, 3.0))  # a wide view: r > 1, the wide range
    narrow = Scene({1: Camera.pinhole(W, H, 4 * F)}, frames)
    r = 2.0 * W / (2 * 4 * F)
    assert r < 0.5 and np.allclose(sweep_depth_bounds(narrow, "object"), (2.0 - r, 2.0 + r))
    assert np.allclose(sweep_depth_bounds(narrow), (1.0, 3.0))  # the default is unchanged
    assert sweep_depth_bounds(plane_scene(), "object") == (1.0, 4.0)  # known bounds still win
    assert sweep_depth_bounds(plane_scene()) == (1.0, 4.0)  # known bounds win


def test_flow_fallback_renders_a_novel_view_of_the_plane(tmp_path, tiny_cfg):
    """fallback="flow": the gate's alternative is the two sources aligned by optical flow; a midpoint of
    the textured plane comes out close to the truth, and the flow-aligned plane is what the decoder sees."""
    from sparself.core.warp import flow_pair
    from sparself.model import sweep_volume

    scene = plane_scene()
    run = train(scene, tmp_path / "run", tiny_cfg(epochs=3, fallback="flow"), progress=False)
    mid = Frame("mid", Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([2.5 * 0.08, 0, 0])), 1, 2.5)
    out = synthesize(run, scene, [mid])[0]
    gt = render_plane(2.5 * 0.08)
    assert float(np.mean((out[4:-4, 4:-4] - gt[4:-4, 4:-4]) ** 2)) < 0.1 * float(np.var(gt))
    w0, w1 = flow_pair(render_plane(2 * 0.08), render_plane(3 * 0.08), 0.5)
    assert float(np.mean(np.abs(0.5 * (w0 + w1) - gt)[4:-4, 4:-4])) < float(
        np.mean(np.abs(render_plane(2 * 0.08) - gt)[4:-4, 4:-4])
    )
    src = torch.rand(2, 3, H, W)
    plain = torch.rand(2, 3, H, W)
    K = torch.tensor(scene.cameras[1].K, dtype=torch.float32)
    w2c = torch.eye(4).expand(2, 4, 4)
    x = sweep_volume(src, K.expand(2, 3, 3), w2c, K, torch.eye(4), torch.tensor([0.5, 0.25]), (H, W), plain)
    assert torch.equal(x[0:3, -1], plain[0]) and torch.equal(x[3:6, -1], plain[1])
    assert torch.all(x[6:8, -1] == 0.5)  # validity 1 x blend weights (equal: both sources at distance 0)


def test_configs_saved_before_the_fallback_option_load_as_the_plain_blend(tiny_cfg):
    old = {k: v for k, v in tiny_cfg().to_json().items() if k != "fallback"}
    assert TrainConfig.from_json(old).fallback == "blend"
    assert TrainConfig.from_json(tiny_cfg().to_json()).fallback == "flow" == TrainConfig().fallback
    with pytest.raises(ConfigError, match="fallback must be one of flow, blend, got .median."):
        tiny_cfg(fallback="median")


def test_four_sources_train_reload_and_synthesize_with_confidence(tmp_path, tiny_cfg):
    """--sources 4: trains, reloads from its folder with the same decoder, and synthesizes a view with
    its confidence map; sources < 2 is refused."""
    from sparself.synthesis.synthesize import synthesize_with_confidence

    scene = plane_scene()
    run = train(scene, tmp_path / "run", tiny_cfg(epochs=1, sources=4), progress=False)
    assert run.model.decoder.attend is not None
    again = load_run(tmp_path / "run")
    assert again.cfg.sources == 4
    target = dataclasses.replace(scene.frames[3], index=3.5, image=None, path=None)
    a = synthesize_with_confidence(run, scene, [target])
    b = synthesize_with_confidence(again, scene, [target])
    assert a.images.shape == (1, SH, SW, 3) and a.confidence.shape == (1, SH, SW)
    assert np.array_equal(a.images, b.images) and 0 <= a.confidence.min() and a.confidence.max() <= 1
    with pytest.raises(ConfigError, match="sources"):
        TrainConfig(sources=1)


def test_ring_range_option_reaches_the_config_from_the_command_line(tiny_cfg):
    """--ring-range is generated from the TrainConfig field (default object); a bad value is a
    ConfigError; old run configs without it load as wide (the earlier rule)."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "sparself.cli", "train", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "--ring-range" in out.stdout
    assert TrainConfig().ring_range == "object"
    old = {k: v for k, v in tiny_cfg(ring_range="object").to_json().items() if k not in ("ring_range", "end_targets")}
    assert TrainConfig.from_json(old).ring_range == "wide" and TrainConfig.from_json(old).end_targets
    assert TrainConfig.from_json(tiny_cfg(ring_range="object").to_json()).ring_range == "object"
    with pytest.raises(ConfigError, match="ring_range must be one of wide, object, got .tight."):
        tiny_cfg(ring_range="tight")


def test_end_targets_off_trains_only_on_targets_between_their_sources():
    """On an open line the leave-one-out targets at the ends extrapolate (t outside [0, 1]): with
    end_targets off the loss never visits them; on; or with fewer than 2 inner targets, it visits all."""
    from sparself.model import PoseNorm
    from sparself.model.query import Sources, leave_one_out
    from sparself.synthesis.train import trained_targets

    src = Sources.from_scene(plane_scene(6)).posed(PoseNorm((0.0, 0.0, 0.0), 1.0), np.array([2.0, 3.0]))
    q = leave_one_out(src)
    assert trained_targets(q, False).tolist() == [False, True, True, True, True, False]
    assert trained_targets(q, True).all()
    three = leave_one_out(Sources.from_scene(plane_scene(3)).posed(PoseNorm((0.0, 0.0, 0.0), 1.0)))
    assert trained_targets(three, False).all()  # only one inner target: keep them all
    assert not TrainConfig().end_targets and TrainConfig(end_targets=True).end_targets


def test_a_resumable_run_continues_in_its_own_folder_and_other_options_train_in_another(tmp_path, tiny_cfg, caplog):
    from sparself.synthesis.train import train_resumable

    scene = plane_scene()
    one = train_resumable(tmp_path, scene, tiny_cfg(epochs=1))
    with caplog.at_level(logging.INFO, logger="sparself"):
        more = train_resumable(tmp_path, scene, tiny_cfg(epochs=2))  # more epochs: the same run, continued
    assert more.path == one.path and "resuming" in caplog.text
    assert torch.load(more.path / "checkpoint.pt", weights_only=False)["epoch"] == 2
    other = train_resumable(tmp_path, scene, tiny_cfg(epochs=1, planes=4))
    moved = train_resumable(tmp_path, scene.subset(range(len(scene) - 1)), tiny_cfg(epochs=1))
    assert len({one.path, other.path, moved.path}) == 3 and {p.parent for p in (other.path, moved.path)} == {tmp_path}
