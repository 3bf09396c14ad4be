"""The code's shape (issue 11): short functions, no private helpers across modules, one decoder signature,
and one source of truth per option (the command line is built from the dataclasses)."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import json
from pathlib import Path

import pytest

from sparself.cli import build_parser
from sparself.evaluate import EvalConfig
from sparself.model.decoders import DECODERS
from sparself.plan import PlanConfig
from sparself.train import TrainConfig

SRC = Path(__file__).resolve().parents[1] / "src" / "sparself"
MAX_LINES = 60


def _trees():
    for p in sorted(SRC.rglob("*.py")):
        yield p.relative_to(SRC), ast.parse(p.read_text())


def test_no_function_in_src_is_longer_than_a_screen():
    long = [f"{p}:{n.lineno} {n.name} ({n.end_lineno - n.lineno + 1} lines)" for p, t in _trees() for n in ast.walk(t)
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.end_lineno - n.lineno + 1 > MAX_LINES]
    assert not long, "functions over 60 lines: " + "; ".join(long)


def test_no_module_imports_a_private_name_of_another_module():
    bad = [f"{p}: from {'.' * n.level}{n.module or ''} import {a.name}" for p, t in _trees() for n in ast.walk(t)
           if isinstance(n, ast.ImportFrom) and n.level > 0 for a in n.names
           if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, bad


def test_every_decoder_takes_sources_queries_and_context():
    for cls in DECODERS.values():
        assert list(inspect.signature(cls.forward).parameters) == ["self", "sources", "queries", "ctx"], cls
        assert list(inspect.signature(cls.with_confidence).parameters) == ["self", "sources", "queries", "ctx"], cls
        assert isinstance(cls.reads_sources, bool) and callable(cls.native_hw)


def _subparser(name: str):
    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    return sub.choices[name]


def _dests(p) -> set[str]:
    return {a.dest for a in p._actions}


def test_every_training_and_plan_option_is_on_the_command_line():
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    assert fields <= _dests(_subparser("train"))
    assert fields - {"size"} <= _dests(_subparser("densify"))  # densify trains at --out-size
    assert "--size" not in _subparser("densify")._option_string_actions
    plan = {f.name for f in dataclasses.fields(PlanConfig)}
    assert plan <= _dests(_subparser("plan")) and plan <= _dests(_subparser("densify"))
    # evaluate sets seed, size, epochs and holdout itself; the rest reaches the network
    assert fields - {"seed", "size", "epochs", "holdout"} <= _dests(_subparser("evaluate"))


def test_evaluate_options_reach_the_network_config(monkeypatch):
    from sparself import cli, evaluate

    seen = {}
    monkeypatch.setattr(evaluate, "evaluate", lambda paths, out, cfg, overwrite=False: seen.setdefault("cfg", cfg) and
                        {"scenes": []})
    cli.main(["evaluate", "x", "--out", "y", "--quick", "--decoder", "fc", "--fallback", "blend", "--no-gate",
              "--recon", "mpi", "--seeds", "2", "-q"])
    cfg = seen["cfg"]
    assert (cfg.train.decoder, cfg.train.fallback, cfg.train.gate) == ("fc", "blend", False)
    assert cfg.reconstructors == ("mpi",) and cfg.seeds == 2 and cfg.size == EvalConfig.quick().size


def test_train_options_parse_into_the_config_and_config_json_round_trips(tmp_path):
    from sparself.cli import _train_config

    args = _subparser("train").parse_args(["s", "--out", "o", "--holdout", "3,10", "--windows", "3,7",
                                           "--finetune-backbone", "no", "--no-context", "--lr", "0.01"])
    cfg = _train_config(args)
    assert cfg.holdout == (3, 10) and cfg.windows == (3, 7) and cfg.finetune_backbone is False
    assert cfg.context is False and cfg.lr == 0.01 and cfg.epochs == TrainConfig().epochs
    path = tmp_path / "config.json"
    path.write_text(json.dumps(cfg.to_json()))
    assert TrainConfig.from_json(json.loads(path.read_text())) == cfg
    with pytest.raises(SystemExit):
        _subparser("train").parse_args(["s", "--out", "o", "--holdout", "3,x"])
