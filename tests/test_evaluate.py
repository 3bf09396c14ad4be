"""The held-out protocol: split rules, held-out images never read outside scoring, failures isolated."""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from planescene import F, H, W, render_plane
from sparself.capture.images import resize_image, save_image
from sparself.capture.io.dense import SelfCheck
from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.geometry import Pose
from sparself.evaluation import evaluate as ev
from sparself.evaluation import protocol, scene_eval
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.instruments import network_factory
from sparself.evaluation.results import AT_VIEWS, NETWORK_WEIGHTED, ScoredSet, SeededSets
from sparself.evaluation.scene_results import SceneFailure, SceneResult
from sparself.evaluation.split import evenly_spaced, gap_truth, holdout_indices, make_split

# ---- split rules ----------------------------------------------------------------------------------


def test_holdout_is_every_kth_interior_frame():
    assert holdout_indices(20, 8) == [8, 16]
    assert holdout_indices(17, 8) == [8]  # 16 is the last frame: not interior
    assert holdout_indices(184, 8)[:3] == [8, 16, 24] and holdout_indices(184, 8)[-1] == 176
    assert holdout_indices(9, 8) == []  # frame 8 is the last one: not interior


def test_evenly_spaced_inputs_and_midpoint_truth():
    rest = [0, 1, 2, 3, 5, 6, 7, 9, 10, 11, 12]
    inputs = evenly_spaced(rest, 4)
    # positions round(linspace(0, 10, 4)) = 0, 3, 7, 10 -> frames 0, 3, 9, 12
    assert inputs == [0, 3, 9, 12]
    avail = [i for i in rest if i not in inputs]
    # gaps (0,3): 1 and 2 are equally near 1.5 -> the earlier; (3,9): 6 is exactly the middle; (9,12): 10 (tie)
    assert gap_truth(avail, inputs) == [1, 6, 10]
    assert gap_truth([], [0, 3]) == [None]
    assert evenly_spaced([4, 5], 5) == [4, 5]


def test_make_split_dense_and_sparse():
    cfg = EvalConfig(inputs=25)
    d = make_split(184, replace(cfg, extrapolation_margin=0))  # the margin: test_evaluate_extrapolation.py
    assert d.kind == "dense" and len(d.inputs) == 25 and d.eval == holdout_indices(184, 8)
    assert d.inputs[0] == 0 and d.inputs[-1] == 183
    assert not set(d.eval) & set(d.inputs) and not set(d.eval) & set(d.between)
    assert all(any(a < b < c for b in d.between) for a, c in zip(d.inputs[:-1], d.inputs[1:]))
    s = make_split(16, cfg)  # Middlebury sparse ring
    assert s.kind == "sparse" and s.eval == [1, 3, 5, 7, 9, 11, 13] and s.inputs == [0, 2, 4, 6, 8, 10, 12, 14, 15]
    assert s.between == []


# ---- end to end on a tiny synthetic capture ---------------------------------------------------------

N_FRAMES = 24


def _capture(folder: Path) -> Scene:
    """24 cameras sliding along x over the textured plane, images written as PNG files."""
    folder.mkdir(parents=True, exist_ok=True)
    cam = Camera.pinhole(W, H, F)
    frames = []
    for i in range(N_FRAMES):
        pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([0.03 * i, 0.0, 0.0]))
        path = folder / f"img{i:03d}.png"
        save_image(path, render_plane(pose, cam))
        frames.append(Frame(path.name, pose, 1, float(i), path))
    return Scene({1: cam}, frames, bounds=(1.0, 10.0), source=folder)


class _NearestRenderer:
    def __init__(self, scene: Scene):
        self.scene = scene

    def render(self, pose, camera):
        i = int(np.argmin(np.linalg.norm(self.scene.centers() - pose.center, axis=1)))
        return resize_image(self.scene.load(i), (camera.width, camera.height))


def _tiny_cfg(**kw) -> EvalConfig:
    base = dict(
        size=32,
        inputs=5,
        holdout_every=4,
        n_mid=2,
        n_extra=1,
        seeds=2,
        baselines=("nearest", "blend"),
        densify_baselines=("blend",),
        examples=1,
        lpips=False,
        progress=False,
        check_steps=10,
    )
    base.update(kw)
    return EvalConfig(**base)


def _hooks():
    from sparself.recon.nerf import fit as nerf_fit
    from sparself.synthesis.baselines import BASELINES

    calls = []

    def network(scene, seed):  # a "trained" synthesizer: blend, but seed-dependent so std is real
        calls.append(seed)

        def synth(sc, targets):
            return np.clip(BASELINES["blend"](sc, targets) + 0.01 * seed, 0, 1)

        return synth

    recs = {
        "nearest": _NearestRenderer,
        "nerf": lambda sc: nerf_fit(
            sc, steps=15, batch_rays=256, n_samples=8, levels=(8, 16), hidden=16, progress=False, threads=1
        ),
    }
    return dict(network=network, reconstructors=recs), calls


def _capture_of(folder: Path, n: int, monkeypatch) -> Scene:
    monkeypatch.setattr(sys.modules[__name__], "N_FRAMES", n)
    return _capture(folder)


def test_the_report_notes_held_out_frames_that_lie_at_planned_views(tmp_path, monkeypatch):
    # 9 frames, 5 inputs: the even frames are the inputs, the odd ones held out, and the paper's midpoints
    # of the gaps planned (3 and 7 of them, at 2 of the 4 scored frames)
    ev = protocol.start_scene(_capture_of(tmp_path / "nine", 9, monkeypatch), _tiny_cfg(), None)
    assert (ev.split.inputs, ev.scored, [f.index for f in ev.planned][:2]) == ([0, 2, 4, 6, 8], [1, 3, 5, 7], [3, 7])
    assert ev.at_views(ev.planned).tolist() == [False, True, False, True]
    said = AT_VIEWS + "2 of 4 scored held-out frames lie at a planned view's pose"
    assert any(n.startswith(said) for n in ev.result.notes)
    # 24 frames: every held-out frame is at least a frame from the planned poses (a quarter gap is under one)
    dense = protocol.start_scene(_capture_of(tmp_path / "dense", 24, monkeypatch), _tiny_cfg(), None)
    assert not dense.at_views(dense.planned).any()
    assert not any("planned view's pose" in n for n in dense.result.notes)


def test_the_checked_rows_note_gives_its_change_over_n_away_from_its_kept_views(tmp_path, monkeypatch):
    from sparself.evaluation.checked import _at_kept_views
    from sparself.evaluation.results import FrameScore

    ev = protocol.start_scene(_capture_of(tmp_path / "nine", 9, monkeypatch), _tiny_cfg(), None)

    def row(psnrs, seed):
        return ScoredSet([FrameScore(f"f{i}", i, p, 0.5, None) for i, p in zip(ev.scored, psnrs)], seed=seed)

    base = {0: row([20, 20, 20, 20], 0), 1: row([21, 21, 21, 21], 1)}
    checked = [row([21, 25, 19.5, 26], 0), row([21, 21, 21, 21], 1)]  # seed 0 kept the views at frames 3 and 7
    note = _at_kept_views(ev, "3dgs", [ev.planned[:2], []], checked, base)
    assert note is not None and "per seed 2/4, 0/4" in note
    assert "at the other scored frames +0.25 / +0.00 dB" in note  # seed 0: (+1 - 0.5) / 2 at frames 1 and 5
    assert _at_kept_views(ev, "3dgs", [[], []], checked, base) is None


def test_held_out_images_are_never_read_outside_scoring(tmp_path, monkeypatch):
    scene = _capture(tmp_path / "cap")
    cfg = _tiny_cfg()
    split = make_split(N_FRAMES, cfg)
    assert split.kind == "dense"
    vault = tmp_path / "vault"
    vault.mkdir()
    held = [scene.frames[i].path for i in split.eval]
    for p in held:  # held-out images are gone from where the scene says they are
        shutil.move(str(p), vault / p.name)
    read = []
    real_load = scene_eval.load_truth

    def scoring_only(frame, size):
        if frame.path is not None and not frame.path.exists():
            read.append(frame.name)
            frame = replace(frame, path=vault / frame.path.name)
        return real_load(frame, size)

    monkeypatch.setattr(scene_eval, "load_truth", scoring_only)
    hooks, calls = _hooks()
    out = tmp_path / "out"
    res = ev.evaluate([scene], out, cfg, **hooks)
    s = res.scenes[0]
    assert isinstance(s, SceneResult) and s.status == "ok", s
    assert set(read) == {scene.frames[i].name for i in split.eval}  # and scored
    assert calls == [0, 1]
    for r in ("nearest", "nerf"):
        d = s.densification[r]
        assert d.status == "ok", d.error
        base, net, oracle = d.rows["base"], d.rows["sparself"], d.rows["oracle"]
        assert isinstance(base, ScoredSet) and isinstance(net, SeededSets) and isinstance(oracle, ScoredSet)
        assert base.views == 5 and net.views == 8 and oracle.views == 8
        assert len(base.frames) == len(split.eval)
    # what densify writes for the NeRF, checked on held-back *inputs* only (the held-out photos are in the vault)
    checked = s.densification["nerf"].rows["sparself_checked"]
    assert isinstance(checked, SeededSets) and len(checked.per_seed) == 2
    inputs = {scene.frames[i].name for i in split.inputs}
    for p in checked.per_seed:
        assert isinstance(p.decision, SelfCheck)
        assert set(p.decision.validation) <= inputs and p.decision.recon == "nerf"
    assert "sparself_checked" not in s.densification["nearest"].rows  # no densify --recon for it
    # seed-dependent synthesizer: 2 seeds give a real spread
    net_vs = s.synthesis.held_out["sparself"]
    assert isinstance(net_vs, SeededSets) and len(net_vs.per_seed) == 2
    assert (net_vs.mean("psnr")[1] or 0) > 0
    # planned truth: snapped to real non-held-out frames strictly between inputs (2 midpoints) or beyond the
    # last one (1 extrapolation)
    truths = [p.truth for p in s.split.planned if p.truth is not None]
    assert len(truths) == 3 and not set(truths) & set(split.eval) and not set(truths) & set(split.inputs)
    assert sum(t > split.inputs[-1] for t in truths) == 1
    # blend at held-out poses beats nothing-better-than-nearest? both are scored, with finite PSNR
    assert s.synthesis.held_out["blend"].mean("psnr")[0] is not None
    # outputs: JSON with settings + versions (the results' own JSON), report with the tables and figures
    data = json.loads((out / "results.json").read_text())
    assert data == json.loads(json.dumps(res.to_json()))
    assert data["settings"]["inputs"] == [5] and "torch" in data["settings"]["versions"]
    md = (out / "report.md").read_text()
    assert "Densification: N input views vs N + synthesized views" in md
    assert "| Scene | nearest N | nearest N+synth | nearest change | nerf N |" in md
    assert "N + real (oracle)" in md and "share of oracle gain" in md
    assert "DietNeRF" in md or "dietnerf" in md
    assert (out / "report.html").is_file() and list((out / "figures").glob("grid_*.png"))
    assert (out / "examples" / "cap" / "cameras.png").is_file()


def test_a_failing_scene_is_reported_and_the_others_go_on(tmp_path):
    good = _capture(tmp_path / "good")
    broken = _capture(tmp_path / "broken")
    first_input = broken.frames[make_split(N_FRAMES, _tiny_cfg()).inputs[0]]
    first_input.path.write_bytes(b"not a png")  # an input frame: synthesis cannot run
    hooks, _ = _hooks()
    hooks["reconstructors"] = {"nearest": _NearestRenderer}
    out = tmp_path / "out"
    res = ev.evaluate([broken, tmp_path / "no_such_scene", good], out, _tiny_cfg(seeds=1), **hooks)
    status = [s.status for s in res.scenes]
    assert status == ["failed", "failed", "ok"]
    assert isinstance(res.scenes[0], SceneFailure) and first_input.name in res.scenes[0].error
    md = (out / "report.md").read_text()
    assert "Scenes that failed" in md and "no_such_scene" in md


def test_cli_evaluate_refuses_an_empty_scene_list(tmp_path, capsys):
    from sparself.cli import main

    rc = main(["evaluate", "--out", str(tmp_path / "o")])
    assert rc != 0 and "no scenes given" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_cli_evaluate_end_to_end_with_the_real_network(tmp_path, capsys):
    """sparself evaluate on a capture on disk: reader, CNN-LSTM (1 epoch), baselines, MPI, report."""
    import torch

    from sparself.capture.io import write_scene
    from sparself.cli import main

    torch.set_num_threads(1)
    scene = _capture(tmp_path / "cap_images")
    write_scene(scene, tmp_path / "cap", formats=("llff",))
    out = tmp_path / "report"
    rc = main(
        [
            "evaluate",
            str(tmp_path / "cap"),
            "--out",
            str(out),
            "--quick",
            "--size",
            "32",
            "--inputs",
            "5",
            "--epochs",
            "1",
            "--recon",
            "mpi",
            "-q",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    data = json.loads((out / "results.json").read_text())
    s = data["scenes"][0]  # the file as written
    assert s["status"] == "ok" and s["name"] == "cap"
    assert "sparself" in s["view_synthesis"] and s["densification"]["mpi"]["status"] == "ok"
    # the weighted row's weight choice: the real network synthesizes again from the 4 inputs not held back
    sel = s["densification"]["mpi"][NETWORK_WEIGHTED]["per_seed"][0]["selection"]
    assert len(sel["validation_sources"]) == 4 and not set(sel["validation_sources"]) & set(sel["validation_views"])
    assert data["settings"]["epochs"] == 1 and data["settings"]["size"] == 32
    assert "| Scene | mpi N | mpi N+synth | mpi change |" in (out / "report.md").read_text()


def test_missing_imagenet_weights_are_reported_once_per_evaluation(tmp_path, monkeypatch, caplog):
    """Two seeds train two networks, but the "no ImageNet weights" note is said once."""
    import logging

    import torch

    torch.set_num_threads(1)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    scene = _capture(tmp_path / "cap_images")
    with caplog.at_level(logging.INFO, logger="sparself"):  # a note (INFO): it holds on every offline run
        make = network_factory(EvalConfig(size=32, epochs=1, seeds=2, progress=False))
        for seed in (0, 1):
            make(scene, seed)
    said = [r for r in caplog.records if "no ImageNet weights" in r.getMessage()]
    assert len(said) == 1


def test_partial_results_are_handed_out_after_each_step(tmp_path):
    scene = _capture(tmp_path / "cap")
    hooks, _ = _hooks()
    hooks["reconstructors"] = {"nearest": _NearestRenderer, "nearest2": _NearestRenderer}
    seen = []

    def on_partial(res):  # a copy of what is finished at each call
        seen.append((sorted(res.synthesis.held_out), sorted(res.densification)))

    final = protocol.evaluate_scene(scene, _tiny_cfg(seeds=1), None, on_partial=on_partial, **hooks)
    assert [s[1] for s in seen] == [[], [], ["nearest"], ["nearest", "nearest2"]]
    assert seen[0][0] == ["sparself"] and seen[1][0] == ["blend", "nearest", "sparself"]
    assert final.densification["nearest2"].status == "ok"


def test_the_fixers_views_are_scored_wherever_it_was_used_even_when_no_view_was_kept(tmp_path, monkeypatch):
    from sparself.capture.io.dense import FixerCheck
    from sparself.evaluation import checked as checked_row
    from sparself.evaluation import selfcheck
    from sparself.evaluation.fixing import FixerFit
    from sparself.evaluation.results import NETWORK_FIXED
    from sparself.model.fixer import Fixer

    used = lambda pairs, steps, seed, groups=None: FixerFit(  # noqa: E731
        Fixer(), FixerCheck(pairs.names, 20.0, 19.0, 21.0, True), (Fixer(),) * len(groups or pairs.names)
    )
    monkeypatch.setattr(selfcheck, "validated_fixer", used)
    strict = checked_row.check_config
    monkeypatch.setattr(checked_row, "check_config", lambda *a: replace(strict(*a), min_gain=99.0))
    hooks, _ = _hooks()
    hooks["reconstructors"] = {"nerf": hooks["reconstructors"]["nerf"]}
    s = ev.evaluate([_capture(tmp_path / "cap")], tmp_path / "out", _tiny_cfg(), **hooks).scenes[0]
    rows = s.densification["nerf"].rows
    assert all(p.decision.kept == () and p.decision.fixer.used for p in rows["sparself_checked"].per_seed)
    fixed = rows[NETWORK_FIXED]
    assert isinstance(fixed, SeededSets) and [p.seed for p in fixed.per_seed] == [0, 1]
    assert all(len(p.frames) == len(rows["base"].frames) for p in fixed.per_seed)


class _SeededRenderer(_NearestRenderer):
    """The nearest photo, brightened by its fit's seed: a reconstructor whose result depends on its seed."""

    def __init__(self, scene: Scene, seed: int):
        super().__init__(scene)
        self.seed = seed

    def render(self, pose, camera):
        return np.clip(super().render(pose, camera) + 0.02 * self.seed, 0, 1)


def test_every_row_of_a_seed_is_fitted_with_that_seeds_reconstruction_seed(tmp_path, monkeypatch):
    from sparself.evaluation.results import paired_change
    from sparself.recon import nerf
    from sparself.recon.pool import Fitter

    seen: list[tuple[int, int]] = []  # (views, seed) of every fit

    def fit(scene, seed=0, **_):
        seen.append((len(scene), seed))
        return _SeededRenderer(scene, seed)

    monkeypatch.setattr(nerf, "fit", fit)
    hooks, _ = _hooks()
    hooks["reconstructors"] = {"nerf": Fitter("nerf", {"seed": 0})}
    s = ev.evaluate([_capture(tmp_path / "cap")], tmp_path / "out", _tiny_cfg(recon_seed=5), **hooks).scenes[0]
    rows = s.densification["nerf"].rows
    for key in ("base", "sparself", "blend", "oracle", "sparself_checked"):
        row = rows[key]
        assert isinstance(row, SeededSets) and [p.seed for p in row.per_seed] == [0, 1], key
    base = rows["base"]
    assert isinstance(base, SeededSets)
    b0, b1 = (p.raw_mean("psnr") for p in base.per_seed)
    assert b0 != b1  # N alone was fitted twice, with seeds 5 and 6
    assert {seed for _, seed in seen} == {5, 6}  # the self-check's fits too
    assert sum(1 for views, _ in seen if views == 5) >= 2  # N alone, once per seed
    net = rows["sparself"]
    assert isinstance(net, SeededSets)
    diffs = [p.raw_mean("psnr") - q.raw_mean("psnr") for p, q in zip(net.per_seed, base.per_seed)]
    change, spread = paired_change(net, base)
    assert change == pytest.approx(np.mean(diffs)) and spread == pytest.approx(np.std(diffs))


def test_the_checked_row_runs_densifys_check_with_the_evaluations_choices():
    from types import SimpleNamespace

    from sparself.evaluation.checked import check_config

    cfg = EvalConfig(
        check_plan="paper",
        check_gain_gap="own",
        check_steps=123,
        check_size=48,
        recon_seed=4,
        check_loss_within_gain=False,
    )
    got = check_config(SimpleNamespace(cfg=cfg, net_synths=[object()]), "3dgs", 2)
    assert (got.recon, got.plan_mode, got.gain_gap, got.check_steps, got.check_seed) == ("3dgs", "paper", "own", 123, 6)
    assert got.check_size == 48 and not got.loss_within_gain
    assert check_config(SimpleNamespace(cfg=EvalConfig(), net_synths=[object()]), "3dgs", 0).loss_within_gain
    assert check_config(SimpleNamespace(cfg=cfg, net_synths=[object()]), "nearest", 0) is None  # no check for it


@pytest.mark.parametrize("bad", [{"check_steps": 0}, {"check_size": 7}])
def test_a_check_fit_without_steps_or_pixels_is_refused(bad):
    from sparself.core.errors import ConfigError

    with pytest.raises(ConfigError, match="check_steps must be >= 1 and check_size >= 8"):
        EvalConfig(**bad).validate()


def test_the_cpu_3dgs_far_reach_reaches_its_fits_and_a_reach_short_of_the_points_is_refused():
    from sparself.core.errors import ConfigError
    from sparself.evaluation.instruments import reconstructor

    assert "far_reach" not in reconstructor("splat", EvalConfig(splat_far_reach=(1.0,))).settings  # the fits' own
    assert reconstructor("splat", EvalConfig(splat_far_reach=(5.0,))).settings["far_reach"] == 5.0
    assert reconstructor("splat", EvalConfig()).settings["far_reach"] == 1.0  # the first of 1, 5, then chosen
    for bad in [(0.5,), (1.0, 0.5), ()]:
        with pytest.raises(ConfigError, match="splat_far_reach must be one or more reaches >= 1"):
            EvalConfig(splat_far_reach=bad).validate()


def test_the_seeds_3dgs_self_checks_run_in_turns_on_two_workers_decide_as_one_after_the_other(tmp_path, monkeypatch):
    from sparself.evaluation import checked
    from sparself.recon.pool import Fitter

    hooks, _ = _hooks()
    splat = dict(steps=0, min_steps_per_view=4, init_points=150, max_gaussians=300, progress=False, seed=0)
    hooks["reconstructors"] = {"3dgs": Fitter("splat", splat)}
    capture, cfg = _capture(tmp_path / "cap"), _tiny_cfg(check_steps=20, densify_baselines=(), weighted=False)
    got = {}
    for workers in (1, 2):
        monkeypatch.setattr(checked, "check_workers", lambda cfg, w=workers: w)
        rows = ev.evaluate([capture], tmp_path / f"out{workers}", cfg, **hooks).scenes[0].densification["3dgs"].rows
        got[workers] = {
            key: [(p.raw_mean("psnr"), repr(p.decision)) for p in row.per_seed]  # repr: a NaN equals itself
            for key, row in rows.items()
            if isinstance(row, SeededSets)
        }
    assert set(got[1]) >= {"base", "sparself", "oracle", "sparself_checked"}
    assert all("SelfCheck(" in d for _, d in got[1]["sparself_checked"])
    assert got[1] == got[2]


def test_what_each_seed_writes_is_fitted_beside_the_other_checks_as_it_is_alone(tmp_path, monkeypatch):
    # the fit of a seed's kept views runs in the checks' pool, beside the other seeds' checks: it must score
    # as the same fit made on its own, and only for the seed that keeps views
    from sparself.evaluation import checked, instruments
    from sparself.evaluation.selfcheck import Checked
    from sparself.recon.pool import FitPool, Fitter

    def keeping(inputs, planned, plan, synth, cfg, sources=None, fits=None, other=None):
        if cfg.check_seed % 2:  # the second seed keeps no view, the first two
            return planned, Checked([], np.zeros((0, H, W, 3), np.float32), None, None), None
        return planned, Checked(planned[:2], np.asarray(synth(inputs, planned[:2])), None, None), None

    pooled = []
    real_run = FitPool.run

    def spying(self, jobs):
        pooled.append((self.workers, len(jobs[0][1])))
        return real_run(self, jobs)

    hooks, _ = _hooks()
    splat = dict(steps=0, min_steps_per_view=4, init_points=150, max_gaussians=300, progress=False, seed=0)
    hooks["reconstructors"] = {"3dgs": Fitter("splat", splat)}
    capture, cfg = _capture(tmp_path / "cap"), _tiny_cfg(densify_baselines=(), weighted=False)
    monkeypatch.setattr(checked, "checked_views", keeping)
    monkeypatch.setattr(FitPool, "run", spying)
    got = {}
    for workers in (1, 2):
        monkeypatch.setattr(checked, "check_workers", lambda cfg, w=workers: w)
        monkeypatch.setattr(instruments, "side_by_side", lambda name, w=workers: w)
        pooled.clear()
        rows = ev.evaluate([capture], tmp_path / f"out{workers}", cfg, **hooks).scenes[0].densification["3dgs"].rows
        got[workers] = [p.raw_mean("psnr") for p in rows["sparself_checked"].per_seed]
        base = [p.raw_mean("psnr") for p in rows["base"].per_seed]
        assert (workers, cfg.inputs[0] + 2) in pooled  # the kept views' fit went to the checks' pool
    assert got[1] == got[2]
    assert got[1][0] != base[0] and got[1][1] == base[1]


@pytest.mark.parametrize("check_workers", [2, 1])
def test_the_rows_and_the_checks_fit_in_one_pool_where_they_would_start_as_many_workers(
    tmp_path, monkeypatch, check_workers
):
    # workers spawn and compile once per pool: the self-check takes the rows' pool when it would start as many,
    # and its own pool when not (a --check-workers of its own)
    from sparself.evaluation import checked, instruments
    from sparself.evaluation.selfcheck import Checked
    from sparself.recon.pool import FitPool, Fitter

    def keeping(inputs, planned, plan, synth, cfg, sources=None, fits=None, other=None):
        return planned, Checked(planned[:1], np.asarray(synth(inputs, planned[:1])), None, None), None

    started, used = [], []
    real_enter, real_run = FitPool.__enter__, FitPool.run

    def entering(self):
        started.append(self.workers)
        return real_enter(self)

    def running(self, jobs):
        used.append((id(self), len(jobs)))
        return real_run(self, jobs)

    hooks, _ = _hooks()
    splat = dict(steps=0, min_steps_per_view=4, init_points=150, max_gaussians=300, progress=False, seed=0)
    hooks["reconstructors"] = {"3dgs": Fitter("splat", splat)}
    capture, cfg = _capture(tmp_path / "cap"), _tiny_cfg(densify_baselines=(), weighted=False, seeds=2)
    monkeypatch.setattr(checked, "checked_views", keeping)
    monkeypatch.setattr(checked, "check_workers", lambda cfg: check_workers)
    monkeypatch.setattr(instruments, "side_by_side", lambda name: 2)
    monkeypatch.setattr(FitPool, "__enter__", entering)
    monkeypatch.setattr(FitPool, "run", running)
    ev.evaluate([capture], tmp_path / "out", cfg, **hooks)
    rows_pool = used[0][0]
    assert used[0][1] > 2  # the rows' fits, all at once
    written = [pool for pool, n in used[1:] if n == 1]  # each seed's kept view, fitted in the checks' pool
    assert len(written) == 2
    if check_workers == 2:
        assert started == [2] and written == [rows_pool, rows_pool]
    else:
        assert started == [2, 1] and rows_pool not in written


def test_a_stopped_evaluation_resumes_from_its_fits_to_the_same_results(tmp_path, monkeypatch):
    """An evaluation stopped among its fits keeps those it finished beside its output; ``resume`` fits only the
    others and writes the results a run never stopped writes."""
    from sparself.core.outputs import work_path
    from sparself.recon import pool
    from sparself.recon.pool import Fitter

    hooks, _ = _hooks()
    splat = dict(steps=0, min_steps_per_view=4, init_points=150, max_gaussians=300, progress=False, seed=0)
    hooks["reconstructors"] = {"3dgs": Fitter("splat", splat)}
    capture = _capture(tmp_path / "cap")
    cfg = _tiny_cfg(check_steps=20, densify_baselines=(), weighted=False, seeds=1)
    fit, fitted, stop_at = pool._fitted, [], []

    def counted(fitters, scenes, within):
        if stop_at and len(fitted) >= stop_at[0]:
            raise KeyboardInterrupt
        fitted.extend(scenes)
        return fit(fitters, scenes, within)

    monkeypatch.setattr(pool, "_fitted", counted)
    ev.evaluate([capture], tmp_path / "whole", cfg, **hooks)
    total = len(fitted)
    fitted.clear()
    stop_at.append(4)
    with pytest.raises(KeyboardInterrupt):
        ev.evaluate([capture], tmp_path / "stopped", cfg, **hooks)
    kept = list((work_path(tmp_path / "stopped") / "fits").glob("*.pkl"))
    assert not (tmp_path / "stopped").exists() and len(kept) == len(fitted) >= 4
    done = len(fitted)
    stop_at.clear()
    fitted.clear()
    ev.evaluate([capture], tmp_path / "stopped", cfg, resume=True, **hooks)
    assert len(fitted) == total - done and not work_path(tmp_path / "stopped").exists()
    whole, resumed = (
        json.loads((tmp_path / d / "results.json").read_text())["scenes"][0] for d in ("whole", "stopped")
    )
    for key in ("view_synthesis", "densification"):  # repr: a NaN equals itself; times differ
        assert repr(_untimed(resumed[key])) == repr(_untimed(whole[key])) and "psnr" in repr(whole[key])


def _untimed(value):
    """``value`` (read from results.json) without its timings: every key naming seconds."""
    if isinstance(value, dict):
        return {k: _untimed(v) for k, v in value.items() if "seconds" not in k}
    return [_untimed(v) for v in value] if isinstance(value, list) else value
