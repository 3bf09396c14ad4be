"""Extrapolation scored apart: real frames kept beyond the end inputs of a dense capture, held-out
frames there scored as "extrapolated", planned extrapolations snapped to real photos there."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sparself import batch
from sparself.capture.images import save_image
from sparself.capture.scene import Camera, Frame, Scene
from sparself.core.errors import ConfigError
from sparself.core.geometry import Pose
from sparself.evaluation import evaluate as ev
from sparself.evaluation import protocol
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.results import EXTRAPOLATED, INTERPOLATED
from sparself.evaluation.split import evenly_spaced, holdout_indices, make_split

# ---- the split ------------------------------------------------------------------------------------


def test_auto_margin_on_a_184_frame_capture_keeps_real_photos_beyond_both_end_inputs():
    s = make_split(184, EvalConfig(inputs=25))  # llff_bird's shape: every 8th interior frame held out
    assert s.kind == "dense" and len(s.inputs) == 25 and s.eval == holdout_indices(184, 8)
    # auto: max(round(183 / 26) = 7, 8 + 1) = 9 frames at each end are never inputs
    assert s.inputs[0] == 9 and s.inputs[-1] == 174
    assert s.margin == list(range(0, 8)) + [175] + list(range(177, 184))
    beyond = [i for i in range(184) if i < s.inputs[0] or i > s.inputs[-1]]
    assert not set(beyond) & set(s.inputs) and set(beyond) == set(s.margin) | {8, 176}
    # every frame plays exactly one role
    roles = [s.eval, s.inputs, s.between, s.margin]
    assert sorted(i for r in roles for i in r) == list(range(184))
    # the inputs stay evenly spaced (one real photo at least in every gap) inside the margins
    assert all(any(a < b < c for b in s.between) for a, c in zip(s.inputs[:-1], s.inputs[1:]))
    assert "extrapolation margin of 9 frames" in s.rule and "2 held-out frames there" in s.rule


def test_margin_zero_is_the_split_without_extrapolation():
    for n, kw in ((184, dict(inputs=25)), (24, dict(inputs=5, holdout_every=4))):
        cfg = EvalConfig(extrapolation_margin=0, **kw)
        held = holdout_indices(n, cfg.holdout_every)
        rest = [i for i in range(n) if i not in held]
        inputs = evenly_spaced(rest, max(cfg.inputs))  # the inputs span the capture from first to last frame
        s = make_split(n, cfg)
        assert (s.kind, s.eval, s.inputs, s.margin) == ("dense", held, inputs, [])
        assert s.between == [i for i in rest if i not in inputs] and s.inputs[0] == 0 and s.inputs[-1] == n - 1
        assert {s.group(i) for i in s.eval} == {INTERPOLATED}


def test_groups_partition_the_held_out_frames():
    s = make_split(184, EvalConfig(inputs=25))
    ex = [i for i in s.eval if s.group(i) == EXTRAPOLATED]
    inter = [i for i in s.eval if s.group(i) == INTERPOLATED]
    assert ex == [8, 176] and len(inter) == 20 and sorted(ex + inter) == s.eval
    ring = make_split(16, EvalConfig(inputs=25))  # sparse: the ends are inputs, nothing lies beyond them
    assert ring.kind == "sparse" and ring.margin == [] and {ring.group(i) for i in ring.eval} == {INTERPOLATED}


def test_a_margin_that_leaves_too_few_frames_is_dropped_and_said():
    s = make_split(60, EvalConfig(inputs=25))  # 53 frames after the hold-out, 37 inside a 9-frame margin
    assert s.kind == "dense" and s.inputs[0] == 0 and s.inputs[-1] == 59 and s.margin == []
    assert "too few frames for a 9-frame extrapolation margin" in s.rule
    with pytest.raises(ConfigError, match="extrapolation_margin"):
        EvalConfig(extrapolation_margin=-1).validate()


# ---- scores known per frame -------------------------------------------------------------------------

N, SIDE = 24, 16
LO, HI = 5, 18  # the tiny split's first and last input (inputs 5, 7, 11, 15, 18; see _tiny_cfg)


def _value(i: int) -> float:
    return (40 + 8 * i) / 255.0  # each photo is one flat grey, exact in 8 bits


def _err(i: int) -> float:
    """The fakes' error at frame i: 0.1 (PSNR 20 dB) beyond the end inputs, 0.01 (40 dB) between them."""
    return 0.1 if i < LO or i > HI else 0.01


def _flat(i: int, err: float) -> np.ndarray:
    v = _value(i)
    return np.full((SIDE, SIDE, 3), v - err if v > 0.5 else v + err, np.float32)


def _capture(folder: Path) -> Scene:
    folder.mkdir(parents=True, exist_ok=True)
    cam = Camera.pinhole(SIDE, SIDE, 20.0)
    frames = []
    for i in range(N):
        path = folder / f"img{i:03d}.png"
        save_image(path, _flat(i, 0.0))
        frames.append(
            Frame(path.name, Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([0.03 * i, 0, 0])), 1, float(i), path)
        )
    return Scene({1: cam}, frames, bounds=(1.0, 10.0), source=folder)


def _tiny_cfg(**kw) -> EvalConfig:
    base = dict(
        size=SIDE,
        inputs=5,
        holdout_every=4,
        n_mid=2,
        n_extra=2,
        seeds=2,
        baselines=("fake",),
        densify_baselines=(),
        examples=0,
        lpips=False,
        progress=False,
    )
    return EvalConfig(**{**base, **kw})


def _hooks(seen: list):
    """A network whose seed s doubles the error s times (PSNR - 6.02 dB per seed), a baseline with the
    error table, and a reconstructor whose error halves once it has more than the 5 inputs."""

    def network(scene, seed):
        seen.append(("network", sorted(int(f.index) for f in scene.frames)))
        return lambda sc, targets: np.stack([_flat(round(t.index), _err(round(t.index)) * 2**seed) for t in targets])

    class Renderer:
        def __init__(self, scene):
            self.k = 1.0 if len(scene) == 5 else 0.5
            seen.append(("recon", sorted(round(f.index) for f in scene.frames)))

        def render(self, pose, camera):
            i = round(pose.center[0] / 0.03)
            return _flat(i, _err(i) * self.k)

    fake = lambda sc, targets: np.stack([_flat(round(t.index), _err(round(t.index))) for t in targets])  # noqa: E731
    return dict(network=network, reconstructors={"fake_recon": Renderer}, baselines={"fake": fake})


DB2 = 20 * math.log10(2)  # what doubling the error costs


def _psnr(entry, group=None):
    s = entry["summary"] if group is None else entry["groups"][group]
    return s["psnr"]["mean"]


def test_known_per_frame_scores_give_hand_checked_group_summaries(tmp_path):
    seen = []
    res = protocol.evaluate_scene(_capture(tmp_path / "cap"), _tiny_cfg(), None, **_hooks(seen)).to_json()
    assert res["protocol"]["extrapolated"] == ["img004.png", "img020.png"]  # of held-out 4, 8, 12, 16, 20
    fake = res["view_synthesis"]["fake"]
    assert [f["group"] for f in fake["frames"]] == [EXTRAPOLATED] + [INTERPOLATED] * 3 + [EXTRAPOLATED]
    assert _psnr(fake, EXTRAPOLATED) == pytest.approx(20.0, abs=1e-3)
    assert _psnr(fake, INTERPOLATED) == pytest.approx(40.0, abs=1e-3)
    assert _psnr(fake) == pytest.approx((2 * 20 + 3 * 40) / 5, abs=1e-3)
    net = res["view_synthesis"]["sparself"]  # seeds 0 and 1: mean over seeds of each seed's group mean
    assert _psnr(net, EXTRAPOLATED) == pytest.approx(20 - DB2 / 2, abs=1e-3)
    assert net["groups"][EXTRAPOLATED]["psnr"]["std"] == pytest.approx(DB2 / 2, abs=1e-3)
    assert _psnr(net, INTERPOLATED) == pytest.approx(40 - DB2 / 2, abs=1e-3)
    # planned poses: 2 midpoints (between frames) and 2 extrapolations snapped to margin frames 3 and 19
    # (planned at 5 - 0.2 * 2 = 4.6 and 18 + 0.2 * 3 = 18.6)
    planned = {p["group"]: [] for p in res["protocol"]["planned"]}
    for p in res["protocol"]["planned"]:
        planned[p["group"]].append(p["truth"])
    assert planned[EXTRAPOLATED] == [3, 19] and not set(planned[INTERPOLATED]) & {4, 8, 12, 16, 20}
    assert _psnr(res["extrapolations"]["fake"]) == pytest.approx(20.0, abs=1e-3)
    assert _psnr(res["midpoints"]["fake"]) == pytest.approx(40.0, abs=1e-3)
    assert _psnr(res["extrapolations"]["sparself"]) == pytest.approx(20 - DB2 / 2, abs=1e-3)
    # densification: halving the error adds 6.02 dB in each group; the oracle's real photos included
    d = res["densification"]["fake_recon"]
    for g, db in ((EXTRAPOLATED, 20.0), (INTERPOLATED, 40.0)):
        assert _psnr(d["base"], g) == pytest.approx(db, abs=1e-3)
        assert _psnr(d["sparself"], g) == pytest.approx(db + DB2, abs=1e-3)
        assert _psnr(d["oracle"], g) == pytest.approx(db + DB2, abs=1e-3)
    # no held-out frame is ever a source: the network sees the inputs, the oracle adds margin and between frames
    assert [s for s in seen if s[0] == "network"] == [("network", [5, 7, 11, 15, 18])] * 2
    fits = [s[1] for s in seen if s[0] == "recon"]
    assert fits[0] == [5, 7, 11, 15, 18] and all(not set(f) & {4, 8, 12, 16, 20} for f in fits)
    assert sorted(fits[-1]) == sorted([5, 7, 11, 15, 18] + planned[INTERPOLATED] + [3, 19])  # the oracle


def test_report_rows_for_both_groups_and_seed_merge_keeps_them(tmp_path):
    scene = _capture(tmp_path / "cap")
    out = tmp_path / "out"
    res = ev.evaluate([scene], out, _tiny_cfg(), **_hooks([]))
    md = (out / "report.md").read_text()
    rows = [ln for ln in md.splitlines() if ln.startswith("| cap: extrapolated (2) |")]
    # view synthesis (PSNR, SSIM), Tables 1-3 (PSNR, SSIM), and the reconstructor's comparison (PSNR, SSIM)
    assert len(rows) == 6 and any(
        ln.startswith("| cap: extrapolated (2) | 20.00 | 26.02 ± 0.00 | +6.02 |") for ln in rows
    )
    assert any(ln.startswith("| cap: extrapolated (2) | 16.99 ± 3.01 | 20.00 |") for ln in rows)
    assert "| cap: interpolated (3) | 36.99 ± 3.01 | 40.00 |" in md
    # the reconstructor's comparison: the oracle's share per group too (6.02 of 6.02 dB), also for the weighted refit
    assert "| cap: extrapolated (2) | 20.00 | 26.02 ± 0.00 | 26.02 ± 0.00 | 26.02 | 100% | 100% |" in md
    assert "View synthesis at extrapolated planned poses" in md and "| cap | 16.99 ± 3.01 | 20.00 |" in md
    assert "extrapolated" in (out / "report.html").read_text()
    assert (
        "cap: view synthesis of extrapolated frames: sparself (16.99 dB) does not beat the best baseline, fake "
        "(20.00 dB)." in md
    )
    # batch evaluate: one unit per seed, merged; the groups come back as mean ± std over the seeds
    one = {s: protocol.evaluate_scene(scene, _tiny_cfg(seeds=1, first_seed=s), None, **_hooks([])) for s in (0, 1)}
    merged = batch.merge_seeds([(s, r, Path(f"seed{s}")) for s, r in one.items()]).to_json()
    whole = res.scenes[0].to_json()
    for sec in ("view_synthesis", "extrapolations"):
        assert merged[sec]["sparself"]["summary"]["psnr"] == whole[sec]["sparself"]["summary"]["psnr"]
    net = merged["view_synthesis"]["sparself"]
    for g in (EXTRAPOLATED, INTERPOLATED):  # (LPIPS is NaN without weights: NaN != NaN)
        assert net["groups"][g]["psnr"] == whole["view_synthesis"]["sparself"]["groups"][g]["psnr"]
    assert net["groups"][EXTRAPOLATED]["psnr"]["n_seeds"] == 2
    assert _psnr(merged["densification"]["fake_recon"]["sparself"], EXTRAPOLATED) == pytest.approx(20 + DB2, abs=1e-3)
