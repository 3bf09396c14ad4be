"""batch_units: moved from batch."""

from __future__ import annotations

import dataclasses
import json
import logging
import time
import traceback
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import torch

from sparself.capture.io import read_scene
from sparself.core.errors import ConfigError, InputError, OutputError, SparselfError
from sparself.core.outputs import atomic_file
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.evaluate import evaluate
from sparself.evaluation.results_file import UnitRecord
from sparself.evaluation.scene_results import SceneFailure
from sparself.evaluation.selfcheck import SelfCheckConfig
from sparself.pipeline import DensifyConfig, densify
from sparself.synthesis.plan import PlanConfig

KINDS = ("densify", "evaluate")


RAY_MISSING = (
    "Ray is not installed: pip install 'sparself[ray]' (or pip install ray); "
    "or add --local to run the batch in this process without Ray"
)


@dataclass
class Capture:
    """One manifest entry: a name (unique, file-safe), the capture's path and its own option overrides."""

    name: str
    path: Path
    options: dict = field(default_factory=dict)


@dataclass
class BatchConfig:
    """How the units run. address: None (embedded Ray on this machine), "auto" or "ray://host:port".
    local: no Ray, units one after another in this process. workers: units at a time (default: as many
    as the CPUs (and GPUs) allow). cpus_per_task: CPU threads per unit. gpus_per_task: None = one GPU
    per unit when the cluster has GPUs and the device is not cpu, else none. progress: None = on a terminal."""

    address: str | None = None
    local: bool = False
    workers: int | None = None
    cpus_per_task: int = 1
    gpus_per_task: float | None = None
    progress: bool | None = None

    def validate(self) -> None:
        if self.local and self.address:
            raise SparselfError("--local runs without Ray: it cannot be combined with --address")
        if self.workers is not None and self.workers < 1:
            raise SparselfError(f"--workers must be at least 1, got {self.workers}")
        if self.cpus_per_task < 1:
            raise SparselfError(f"--cpus-per-task must be at least 1, got {self.cpus_per_task}")
        if self.gpus_per_task is not None and self.gpus_per_task < 0:
            raise SparselfError(f"--gpus-per-task must not be negative, got {self.gpus_per_task}")


@dataclass
class Unit:
    """One task: run ``kind`` on ``source`` with ``config`` (a DensifyConfig or EvalConfig, seed set)
    into ``out``; its log and record go to ``logs``; ``threads`` CPU threads."""

    kind: str
    capture: str
    source: Path
    seed: int
    out: Path
    logs: Path
    config: DensifyConfig | EvalConfig
    threads: int = 1

    @property
    def key(self) -> str:
        return self.capture if self.kind == "densify" else f"{self.capture}.seed{self.seed}"

    @property
    def record(self) -> Path:
        return self.logs / f"{self.key}.json"


class UnitResult(UnitRecord):
    """What became of a unit (:class:`sparself.evaluation.results_file.UnitRecord`: status "ok" or "failed"
    with a one-line error, densify's counts of real and synthesized views, skipped: complete from an earlier
    run)."""

    def label(self, kind: str) -> str:
        """The capture, with the seed for an evaluation unit ('bird (seed 1)'; densify has one unit each)."""
        return f"{self.capture} (seed {self.seed})" if kind == "evaluate" else self.capture


@dataclass
class BatchResult:
    kind: str
    out: Path
    units: list[UnitResult]

    @property
    def failed(self) -> list[UnitResult]:
        return [u for u in self.units if u.status != "ok"]


def make_units(kind: str, captures: list[Capture], base, out: Path, threads: int = 1) -> list[Unit]:
    """The units of a batch: one per capture (densify) or per capture and seed (evaluate)."""
    units = []
    for c in captures:
        cfgs: list[tuple[int, DensifyConfig]] | list[tuple[int, EvalConfig]]
        try:
            cfgs = densify_configs(base, c.options) if kind == "densify" else evaluate_configs(base, c.options)
        except (TypeError, ValueError) as e:
            raise InputError(f"{c.path}: bad option in the manifest: {e}") from None
        for seed, cfg in cfgs:
            sub = out / "captures" / c.name
            units.append(
                Unit(
                    kind,
                    c.name,
                    c.path,
                    seed,
                    sub if kind == "densify" else sub / f"seed{seed}",
                    out / "logs",
                    cfg,
                    threads,
                )
            )
    return units


def densify_configs(base: DensifyConfig, options: dict) -> list[tuple[int, DensifyConfig]]:
    plan_keys = {f.name for f in fields(PlanConfig)}
    check_keys = {f.name for f in fields(SelfCheckConfig)}
    own = plan_keys | check_keys | {"out_size"}
    train = replace(base.train, **{k: v for k, v in options.items() if k not in own})
    plan = replace(base.plan or PlanConfig(), **{k: v for k, v in options.items() if k in plan_keys})
    plan.validate()
    check = replace(base.check, **{k: v for k, v in options.items() if k in check_keys})
    cfg = replace(
        base, train=train, plan=plan, check=check, out_size=options.get("out_size", base.out_size), overwrite=True
    )
    return [(train.seed, cfg)]


def evaluate_configs(base: EvalConfig, options: dict) -> list[tuple[int, EvalConfig]]:
    """One config per seed; the first seed's unit also runs the seed-independent parts (baselines, oracle)."""
    cfg = replace(base, **options, progress=False)
    cfg.validate()
    if len(cfg.inputs) > 1:  # a unit's record holds one run per capture
        raise ConfigError(
            f"batch evaluate runs one N at a time, got inputs {','.join(map(str, cfg.inputs))}: run one batch per N, "
            "or `sparself evaluate --inputs` for the sweep"
        )
    first = cfg.first_seed
    out = []
    for seed in range(first, first + cfg.seeds):
        one = replace(cfg, seeds=1, first_seed=seed)
        out.append((seed, one if seed == first else replace(one, baselines=(), densify_baselines=(), oracle=False)))
    return out


def config_json(cfg) -> object:
    return json.loads(json.dumps(dataclasses.asdict(cfg), sort_keys=True, default=str))


def one_line(e: BaseException) -> str:
    """The error as one line, for the report and the terminal."""
    msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
    return msg if isinstance(e, SparselfError) and msg else f"{type(e).__name__}: {msg}".rstrip(": ")


def run_unit(unit: Unit) -> UnitResult:
    """The task body, the same in a Ray worker and in --local: run the stage with ``unit.threads`` CPU
    threads, its log in ``logs/<unit>.log``, then write the unit's record. Exceptions become a failed
    result; an interruption (KeyboardInterrupt, which ray.cancel raises) propagates."""
    unit.logs.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(unit.logs / f"{unit.key}.log", mode="w")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    pkg = logging.getLogger("sparself")
    old_level, threads = pkg.level, torch.get_num_threads()
    # the log file gets INFO; handlers already there (the terminal's, in --local) keep what they showed
    others = [(h, h.level) for h in pkg.handlers]
    for h, level in others:
        h.setLevel(max(level, pkg.getEffectiveLevel()))
    pkg.addHandler(handler)
    pkg.setLevel(min(pkg.getEffectiveLevel(), logging.INFO))
    torch.set_num_threads(unit.threads)  # per unit, not per worker: the same numbers everywhere
    t0 = time.perf_counter()
    try:
        res = (densify_unit if unit.kind == "densify" else evaluate_unit)(unit)
    except Exception as e:
        assert handler.stream is not None  # a FileHandler opens its file at once
        handler.stream.write(traceback.format_exc())
        res = UnitResult(unit.capture, unit.seed, "failed", one_line(e))
    finally:
        torch.set_num_threads(threads)
        pkg.removeHandler(handler)
        pkg.setLevel(old_level)
        for h, level in others:
            h.setLevel(level)
        handler.close()
    res.seconds = time.perf_counter() - t0
    write_record(unit, res)
    return res


def densify_unit(unit: Unit) -> UnitResult:
    assert isinstance(unit.config, DensifyConfig)
    dense = densify(unit.source, unit.out, unit.config, resume=True)  # from what a stopped batch left
    n_syn = sum(bool(f.synthetic) for f in dense.frames)
    return UnitResult(unit.capture, unit.seed, "ok", views=len(dense.frames) - n_syn, synthesized=n_syn)


def evaluate_unit(unit: Unit) -> UnitResult:
    assert isinstance(unit.config, EvalConfig)
    scene = read_scene(unit.source)  # an unreadable capture fails here and writes nothing
    res = evaluate([scene], unit.out, unit.config, overwrite=True, resume=True)
    s = res.scenes[0]
    if s.status != "ok":
        raise SparselfError((s.error if isinstance(s, SceneFailure) else "evaluation failed").splitlines()[0])
    return UnitResult(unit.capture, unit.seed, "ok")


def write_record(unit: Unit, res: UnitResult) -> None:
    with atomic_file(unit.record) as tmp:
        tmp.write_text(
            json.dumps(
                {
                    **res.to_json(),
                    "skipped": False,
                    "source": str(unit.source),
                    "config": config_json(unit.config),
                },
                indent=1,
            )
        )


def finished(unit: Unit) -> UnitResult | None:
    """The unit's result if an earlier run completed it (output folder and an ok record with the same
    settings), else None. Refuses a complete unit made with other settings rather than replacing it."""
    if not (unit.out.is_dir() and unit.record.is_file()):
        return None
    try:
        rec = json.loads(unit.record.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if rec.get("status") != "ok":
        return None
    if rec.get("config") != config_json(unit.config):
        raise OutputError(
            f"{unit.out}: made by an earlier batch with other settings; use another --out, "
            "or remove that folder to redo it"
        )
    names = {f.name for f in fields(UnitResult)}
    return replace(UnitResult(**{k: v for k, v in rec.items() if k in names}), skipped=True)
