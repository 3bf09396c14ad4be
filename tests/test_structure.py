"""The code's shape: layer folders with imports running only downward and no cycles, short functions, no private
helpers across modules, one decoder signature, and one source of truth per option (the command line is built from
the dataclasses)."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import json
from pathlib import Path

import pytest

from sparself.cli import build_parser
from sparself.evaluation.config import EvalConfig
from sparself.model.decoders import DECODERS
from sparself.synthesis.plan import PlanConfig
from sparself.synthesis.train_config import TrainConfig

SRC = Path(__file__).resolve().parents[1] / "src" / "sparself"
MAX_LINES = 70  # a screen of code as ruff formats it


def _trees():
    for p in sorted(SRC.rglob("*.py")):
        yield p.relative_to(SRC), ast.parse(p.read_text())


def test_no_function_in_src_is_longer_than_a_screen():
    long = [
        f"{p}:{n.lineno} {n.name} ({n.end_lineno - n.lineno + 1} lines)"
        for p, t in _trees()
        for n in ast.walk(t)
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.end_lineno - n.lineno + 1 > MAX_LINES
    ]
    assert not long, f"functions over {MAX_LINES} lines: " + "; ".join(long)


def test_no_module_imports_a_private_name_of_another_module():
    bad = [
        f"{p}: from {'.' * n.level}{n.module or ''} import {a.name}"
        for p, t in _trees()
        for n in ast.walk(t)
        if isinstance(n, ast.ImportFrom) and n.level > 0
        for a in n.names
        if a.name.startswith("_") and not a.name.startswith("__")
    ]
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
    from sparself import cli
    from sparself.evaluation import evaluate
    from sparself.evaluation.results_file import Results

    seen = {}
    monkeypatch.setattr(
        evaluate,
        "evaluate",
        lambda paths, out, cfg, overwrite=False, resume=False: seen.setdefault("cfg", cfg) and Results(),
    )
    cli.main(
        [
            "evaluate",
            "x",
            "--out",
            "y",
            "--quick",
            "--decoder",
            "fc",
            "--fallback",
            "blend",
            "--no-gate",
            "--recon",
            "mpi",
            "--seeds",
            "2",
            "-q",
        ]
    )
    cfg = seen["cfg"]
    assert (cfg.train.decoder, cfg.train.fallback, cfg.train.gate) == ("fc", "blend", False)
    assert cfg.reconstructors == ("mpi",) and cfg.seeds == 2 and cfg.size == EvalConfig.quick().size


def test_train_options_parse_into_the_config_and_config_json_round_trips(tmp_path):
    from sparself.commands import train_config as _train_config

    args = _subparser("train").parse_args(
        [
            "s",
            "--out",
            "o",
            "--holdout",
            "3,10",
            "--windows",
            "3,7",
            "--finetune-backbone",
            "no",
            "--no-context",
            "--lr",
            "0.01",
        ]
    )
    cfg = _train_config(args)
    assert cfg.holdout == (3, 10) and cfg.windows == (3, 7) and cfg.finetune_backbone is False
    assert cfg.context is False and cfg.lr == 0.01 and cfg.epochs == TrainConfig().epochs
    path = tmp_path / "config.json"
    path.write_text(json.dumps(cfg.to_json()))
    assert TrainConfig.from_json(json.loads(path.read_text())) == cfg
    with pytest.raises(SystemExit):
        _subparser("train").parse_args(["s", "--out", "o", "--holdout", "3,x"])


# The package's folders are its layers, lowest first; a module imports only from its own folder or a
# lower layer. Modules at the package root (cli, pipeline, batch) are the shell, the top layer.
LAYERS = {"core": 0, "capture": 1, "model": 2, "synthesis": 3, "recon": 3, "evaluation": 4}
SHELL = 5
SHELL_MODULES = {"__init__", "cli", "commands", "commands_synthesis", "pipeline", "batch", "batch_units", "batch_ray"}


def _module_name(path: Path) -> tuple[str, bool]:
    parts = path.with_suffix("").parts
    is_pkg = parts[-1] == "__init__"
    return ".".join(("sparself",) + (parts[:-1] if is_pkg else parts)), is_pkg


def _imported_modules(path: Path, tree: ast.Module) -> set[str]:
    """Every sparself module ``path`` imports, at top level or inside functions, resolved to absolute names."""
    name, is_pkg = _module_name(path)
    package = name if is_pkg else name.rsplit(".", 1)[0]
    found = set()
    for n in ast.walk(tree):
        if isinstance(n, ast.Import):
            found |= {a.name for a in n.names if a.name.startswith("sparself")}
        elif isinstance(n, ast.ImportFrom):
            base = package.split(".")[: len(package.split(".")) - n.level + 1] if n.level else []
            target = ".".join(base + ([n.module] if n.module else []))
            if target.startswith("sparself"):
                found.add(target)
                found |= {f"{target}.{a.name}" for a in n.names if _is_module(f"{target}.{a.name}")}
    return found


def _is_module(dotted: str) -> bool:
    p = SRC.parent.joinpath(*dotted.split("."))
    return p.with_suffix(".py").exists() or p.is_dir()


def _layer(dotted: str) -> tuple[str, int]:
    parts = dotted.split(".")
    if len(parts) == 1:  # the package itself: only its version string
        return "sparself", -1
    return (parts[1], LAYERS[parts[1]]) if parts[1] in LAYERS else ("shell", SHELL)


def test_every_module_lives_in_a_layer_folder():
    loose = [str(p) for p in SRC.glob("*.py") if p.stem not in SHELL_MODULES]
    assert not loose, f"modules outside the layer folders: {loose}"
    assert {p.name for p in SRC.iterdir() if p.is_dir() and p.name != "__pycache__"} == set(LAYERS)


def test_imports_run_only_downward_between_layers():
    bad = []
    for p, t in _trees():
        here, rank = _layer(_module_name(p)[0])
        for target in _imported_modules(p, t):
            there, target_rank = _layer(target)
            if there != here and target_rank >= rank:
                bad.append(f"{p} ({here}) imports {target} ({there})")
    assert not bad, "imports that run upward or sideways: " + "; ".join(sorted(bad))


def test_no_import_cycles_between_modules():
    graph = {_module_name(p)[0]: _imported_modules(p, t) for p, t in _trees()}
    seen, stack, cycles = set(), [], []

    def visit(m: str) -> None:
        if m in stack:
            cycles.append(" -> ".join(stack[stack.index(m) :] + [m]))
            return
        if m in seen:
            return
        seen.add(m)
        stack.append(m)
        for dep in graph.get(m, ()):
            if dep != m and not m.startswith(dep + "."):  # a package's own __init__ is not a cycle
                visit(dep)
        stack.pop()

    for m in sorted(graph):
        visit(m)
    assert not cycles, cycles
