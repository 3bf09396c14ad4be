"""The weighted row's weight choice: its validation fits train on planned views synthesized
again without the held-back input views; the final weighted fits keep the views synthesized from all inputs."""

from __future__ import annotations

import numpy as np
import pytest

from planescene import noise_scene
from sparself.evaluation import evaluate as ev
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.results import NETWORK_WEIGHTED, SeededSets, WeightChoice
from sparself.evaluation.weighting import ValidationViews, choose_weight, validation_inputs
from sparself.synthesis.synthesize import Synthesized

N_INPUTS = 13  # validation_inputs(13) == [2, 7]: two held-back inputs


def _value(n_sources: int, seed: int) -> float:
    """The fake network's flat grey: it depends on how many sources it was given, and on its seed."""
    return (n_sources + 100 * seed) / 1000


def _fakes(calls: list, fits: list):
    def network(inputs, seed):
        def synth(sources, targets):
            calls.append((seed, [f.name for f in sources.frames], len(targets)))
            h, w = sources.load(0).shape[:2]
            v = _value(len(sources), seed)
            return Synthesized(
                np.full((len(targets), h, w, 3), v, np.float32), np.full((len(targets), h, w), 0.5, np.float32)
            )

        return synth

    class Recon:
        """Records what each fit trained on; renders the frames' weighted mean image everywhere."""

        def __init__(self, sc):
            syn = [f for f in sc.frames if f.synthetic]
            fits.append(
                (
                    [f.name for f in sc.frames if not f.synthetic],
                    {round(float(sc.load(i).mean()), 6) for i, f in enumerate(sc.frames) if f.synthetic},
                    {f.weight for f in syn},
                    bool(syn) and all(f.confidence is not None for f in syn),
                )
            )
            wts = np.array([f.weight for f in sc.frames])
            self.img = np.tensordot(wts, np.stack([sc.load(i) for i in range(len(sc))]), 1) / wts.sum()

        def render(self, pose, camera):
            return self.img

    return dict(network=network, reconstructors={"a": Recon, "b": Recon}, baselines={})


def test_validation_fits_use_views_synthesized_without_the_held_back_inputs(tmp_path):
    scene = noise_scene(40)
    cfg = EvalConfig(
        size=32,
        inputs=N_INPUTS,
        holdout_every=4,
        extrapolation_margin=0,
        n_mid=2,
        n_extra=0,
        seeds=2,
        baselines=(),
        densify_baselines=(),
        oracle=False,
        examples=0,
        lpips=False,
        progress=False,
        synthetic_weights=(0.5, 1.0),
    )
    calls, fits = [], []
    results = ev.evaluate([scene], tmp_path / "out", cfg, **_fakes(calls, fits))
    res = results.ok[0]
    inputs = res.split.inputs
    held_back = [inputs[i] for i in validation_inputs(N_INPUTS)]
    train = [n for n in inputs if n not in held_back]
    assert len(held_back) == 2 and len(train) == 11
    # the network's calls at the 2 planned poses: each seed from all inputs, and once more (seed 0, one call
    # shared by both reconstructors) from the inputs without the held-back ones
    planned_calls = [(seed, srcs) for seed, srcs, t in calls if t == 2]
    assert planned_calls == [(0, inputs), (1, inputs), (0, train)]
    # the validation fits (inputs without the held-back ones): one per weight and reconstructor, on those views
    val = [f for f in fits if f[0] == train]
    assert len(val) == 4 and all(f[1] == {_value(11, 0)} for f in val)
    assert sorted(w for f in val for w in f[2]) == [0.5, 0.5, 1.0, 1.0]
    choices = {}
    for r in ("a", "b"):
        wd = res.densification[r].rows[NETWORK_WEIGHTED]
        assert isinstance(wd, SeededSets) and [p.seed for p in wd.per_seed] == [0, 1]
        sel = choices[r] = wd.per_seed[0].decision
        assert isinstance(sel, WeightChoice)
        assert sel.validation_sources == train and sel.validation_views == held_back and sel.chosen_on_seed == 0
    # the final weighted fits (confidence maps x the chosen weight), per reconstructor and seed: each seed's
    # views from all inputs, as the plain rows' (which carry no confidence maps)
    # (the fake's near-black views pull the mean render away from the noise photos: the smaller weight wins)
    assert [c.weight for c in choices.values()] == [0.5, 0.5]
    final = [f for f in fits if f[0] == inputs and f[3]]
    assert [f[1:3] for f in final] == [({_value(N_INPUTS, s)}, {0.5}) for s in (0, 1)] * 2
    plain = [f[1] for f in fits if f[0] == inputs and f[1] and not f[3]]
    assert plain == [{_value(N_INPUTS, s)} for s in (0, 1)] * 2
    md = (tmp_path / "out" / "report.md").read_text()
    assert "views synthesized from 11 inputs without them" in md
    assert "the network was still trained on all inputs" in md
    # results from before (no validation sources recorded) are not described as made without the held-back views
    for c in choices.values():
        c.validation_sources = None  # (one record shared by the seeds)
    from sparself.evaluation.report import write_report

    md = write_report(results, tmp_path / "older")[0].read_text()
    assert "used the views synthesized from all inputs, held-back ones included" in md
    assert "inputs without them" not in md and "the network was still trained" not in md


def test_choose_weight_refuses_views_synthesized_from_a_held_back_input():
    sc = noise_scene(10)
    planned = [sc.frames[0]]
    views = ValidationViews(np.zeros((1,) + sc.frames[0].image.shape, np.float32), None, [f.name for f in sc.frames])
    with pytest.raises(ValueError, match="held-back input"):
        choose_weight(sc, planned, views, (1.0,), lambda s: None)
