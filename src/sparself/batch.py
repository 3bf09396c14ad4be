"""Many captures at once: ``sparself batch densify|evaluate MANIFEST --out DIR`` on Ray.

Each unit of work (a capture for densify, a capture x seed for evaluate) is one Ray task with explicit
resources, and writes its own folder exactly as the single-capture command does (``densify`` /
``evaluate``, atomically). With no address Ray starts inside the command on this machine's CPUs and
stops at the end; ``address`` joins a running cluster; ``local`` runs the units in this process without
Ray (debugging). Resumable: a unit whose folder and record are complete is skipped. Isolated: a failing
unit is recorded with its one-line error and the others go on. This is the only module that imports ray,
and single-capture code never imports it. Layout of DIR::

    batch.json                     what kind of batch this folder holds (a resumed run must match)
    captures/<name>/               densify: as `sparself densify CAPTURE --out captures/<name>`
    captures/<name>/seed<k>/       evaluate: as `sparself evaluate CAPTURE --seeds 1 --first-seed k`
    logs/<unit>.log, <unit>.json   each unit's log and record (status, error, seconds, settings)
    logs/ray/                      Ray's own logs of the embedded session
    results.json, report.md, report.html, figures/   the combined report
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import json
import logging
import os
import shutil
import tempfile
import time
import traceback
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Iterator

import torch
from tqdm.auto import tqdm

from .errors import InputError, OutputError, SparselfError
from .evaluate import PLANNED_SECTIONS, EvalConfig, evaluate, name_from_source, oracle_share, versions
from .interrupts import signals_interrupt
from .evaluate import read_manifest as read_text_manifest
from .io import read_scene
from .names import check_names
from .outputs import Input, atomic_file, check_not_input, check_output_dir, remove_stale_temps, write_marker
from .pipeline import densify
from .plan import PlanConfig
from .progress import show_progress
from .report import safe_name, write_densify_report, write_report
from .results import NETWORK, NETWORK_WEIGHTED, FrameScore, ScoredSet, SeededSets
from .train import TrainConfig

log = logging.getLogger(__name__)

KINDS = ("densify", "evaluate")
RAY_MISSING = ("Ray is not installed: pip install 'sparself[ray]' (or pip install ray); "
               "or add --local to run the batch in this process without Ray")


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
    config: object
    threads: int = 1

    @property
    def key(self) -> str:
        return self.capture if self.kind == "densify" else f"{self.capture}.seed{self.seed}"

    @property
    def record(self) -> Path:
        return self.logs / f"{self.key}.json"


@dataclass
class UnitResult:
    """What became of a unit. status: "ok" or "failed" (error: one line). views/synthesized: densify's
    counts of real and synthesized views. skipped: complete from an earlier run."""

    capture: str
    seed: int
    status: str
    error: str | None = None
    seconds: float = 0.0
    views: int | None = None
    synthesized: int | None = None
    skipped: bool = False


@dataclass
class BatchResult:
    kind: str
    out: Path
    units: list[UnitResult]

    @property
    def failed(self) -> list[UnitResult]:
        return [u for u in self.units if u.status != "ok"]


# ---- the manifest ------------------------------------------------------------------------------------

def option_names(kind: str) -> frozenset[str]:
    """Per-capture options a manifest may set: the fields of the stage's config dataclasses."""
    if kind == "densify":
        return frozenset({f.name for f in fields(TrainConfig)} | {f.name for f in fields(PlanConfig)} | {"out_size"})
    return frozenset(f.name for f in fields(EvalConfig)) - {"progress", "train"}


def read_manifest(path: Path, kind: str) -> list[Capture]:
    """Captures from a plain list of paths (one a line, # comments) or a JSON/YAML file: a list of entries,
    or {"defaults": {options}, "captures": [entries]}; an entry is a path or {"path", "name", options}.
    Relative paths are relative to the manifest."""
    path = Path(path)
    if path.suffix.lower() not in (".json", ".yaml", ".yml"):
        return _named(path, [Capture("", p) for p in read_text_manifest(path)])
    data = _load_structured(path)
    defaults = data.get("defaults", {}) if isinstance(data, dict) else {}
    entries = data.get("captures") if isinstance(data, dict) else data
    if not isinstance(entries, list) or not entries or not isinstance(defaults, dict):
        raise InputError(f"{path}: expected a list of captures, or {{\"defaults\": {{...}}, \"captures\": [...]}}")
    allowed = option_names(kind)
    caps = []
    for k, e in enumerate(entries):
        e = {"path": e} if isinstance(e, str) else e
        if not isinstance(e, dict) or not isinstance(e.get("path"), str):
            raise InputError(f"{path}: capture {k + 1} needs a \"path\"")
        opts = {**defaults, **{k2: v for k2, v in e.items() if k2 not in ("path", "name")}}
        unknown = sorted(set(opts) - allowed)
        if unknown:
            raise InputError(f"{path}: capture {k + 1}: unknown option(s) {', '.join(unknown)} "
                             f"(known: {', '.join(sorted(allowed))})")
        p = Path(e["path"])
        opts = {k2: tuple(v) if isinstance(v, list) else v for k2, v in opts.items()}
        caps.append(Capture(str(e.get("name") or ""), p if p.is_absolute() else path.parent / p, opts))
    return _named(path, caps)


def _load_structured(path: Path):
    text = path.read_text()
    if path.suffix.lower() == ".json":
        try:
            return json.loads(text)
        except json.JSONDecodeError as e:
            raise InputError(f"{path}: not valid JSON ({e})") from None
    try:
        import yaml
    except ImportError:
        raise InputError(f"{path}: YAML manifests need PyYAML (pip install pyyaml); or write it as JSON") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise InputError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None


def _named(manifest: Path, caps: list[Capture]) -> list[Capture]:
    """Fill in names from the capture folders and refuse duplicates (each names an output folder)."""
    seen: dict[str, Path] = {}
    for c in caps:
        c.name = safe_name(c.name or name_from_source(c.path))
        if c.name in seen:
            raise InputError(f"{manifest}: two captures are named {c.name!r} ({seen[c.name]}, {c.path}); "
                             "give one a \"name\" (JSON manifest)")
        seen[c.name] = c.path
    # each name is a folder under captures/: never '.', '..' or empty, nor two that differ only in case
    check_names([c.name for c in caps], manifest, what="capture name")
    return caps


# ---- units -------------------------------------------------------------------------------------------

def make_units(kind: str, captures: list[Capture], base, out: Path, threads: int = 1) -> list[Unit]:
    """The units of a batch: one per capture (densify) or per capture and seed (evaluate)."""
    units = []
    for c in captures:
        try:
            cfgs = _densify_configs(base, c.options) if kind == "densify" else _evaluate_configs(base, c.options)
        except (TypeError, ValueError) as e:
            raise InputError(f"{c.path}: bad option in the manifest: {e}") from None
        for seed, cfg in cfgs:
            sub = out / "captures" / c.name
            units.append(Unit(kind, c.name, c.path, seed, sub if kind == "densify" else sub / f"seed{seed}",
                              out / "logs", cfg, threads))
    return units


def _densify_configs(base, options: dict) -> list[tuple[int, object]]:
    plan_keys = {f.name for f in fields(PlanConfig)}
    train = replace(base.train, **{k: v for k, v in options.items() if k not in plan_keys and k != "out_size"})
    plan = replace(base.plan or PlanConfig(), **{k: v for k, v in options.items() if k in plan_keys})
    plan.validate()
    cfg = replace(base, train=train, plan=plan, out_size=options.get("out_size", base.out_size), overwrite=True)
    return [(train.seed, cfg)]


def _evaluate_configs(base, options: dict) -> list[tuple[int, object]]:
    """One config per seed; the first seed's unit also runs the seed-independent parts (baselines, oracle)."""
    cfg = replace(base, **options, progress=False)
    cfg.validate()
    first = cfg.first_seed
    out = []
    for seed in range(first, first + cfg.seeds):
        extra = {} if seed == first else dict(baselines=(), densify_baselines=(), oracle=False)
        out.append((seed, replace(cfg, seeds=1, first_seed=seed, **extra)))
    return out


def _config_json(cfg) -> object:
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
        res = (_densify_unit if unit.kind == "densify" else _evaluate_unit)(unit)
    except Exception as e:
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


def _densify_unit(unit: Unit) -> UnitResult:
    dense = densify(unit.source, unit.out, unit.config)
    n_syn = sum(bool(f.synthetic) for f in dense.frames)
    return UnitResult(unit.capture, unit.seed, "ok", views=len(dense.frames) - n_syn, synthesized=n_syn)


def _evaluate_unit(unit: Unit) -> UnitResult:
    scene = read_scene(unit.source)  # an unreadable capture fails here and writes nothing
    res = evaluate([scene], unit.out, unit.config, overwrite=True)
    s = res["scenes"][0]
    if s.get("status") != "ok":
        raise SparselfError(str(s.get("error", "evaluation failed")).splitlines()[0])
    return UnitResult(unit.capture, unit.seed, "ok")


def write_record(unit: Unit, res: UnitResult) -> None:
    with atomic_file(unit.record) as tmp:
        tmp.write_text(json.dumps({**dataclasses.asdict(res), "skipped": False, "source": str(unit.source),
                                   "config": _config_json(unit.config)}, indent=1))


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
    if rec.get("config") != _config_json(unit.config):
        raise OutputError(f"{unit.out}: made by an earlier batch with other settings; use another --out, "
                          "or remove that folder to redo it")
    names = {f.name for f in fields(UnitResult)}
    return replace(UnitResult(**{k: v for k, v in rec.items() if k in names}), skipped=True)


# ---- running the units -------------------------------------------------------------------------------

class _Progress:
    """One bar for the whole batch: units done / running / failed, elapsed and estimated time left."""

    def __init__(self, total: int, enabled: bool | None) -> None:
        self.bar = tqdm(total=total, desc="batch", unit="unit", dynamic_ncols=True,
                        disable=not (show_progress() if enabled is None else enabled))
        self.running = self.failed = 0

    def update(self, running: int, result: UnitResult | None = None) -> None:
        self.running = running
        if result is not None:
            self.failed += result.status != "ok"
            self.bar.update(1)
            if result.status != "ok":
                log.warning("%s seed %d failed: %s", result.capture, result.seed, result.error)
        self.bar.set_postfix_str(f"done {self.bar.n - self.failed}, running {running}, failed {self.failed}")

    def close(self) -> None:
        self.bar.close()


def run_units(units: list[Unit], cfg: BatchConfig, out: Path) -> list[UnitResult]:
    """Run the units (locally or on Ray) behind one progress bar; on an interruption the running units
    are cancelled and their temporary folders removed before KeyboardInterrupt goes on up."""
    bar = _Progress(len(units), cfg.progress)
    try:
        if cfg.local:
            with signals_interrupt(reset=False):
                return _run_local(units, bar)
        with ray_session(cfg, out) as ray, signals_interrupt(reset=False):  # after ray.init, which sets its own
            return _run_ray(ray, units, cfg, bar)
    finally:
        bar.close()
        for u in units:  # leftovers of cancelled or killed units (their processes are gone)
            remove_stale_temps(u.out)
            remove_stale_temps(u.record)


def _run_local(units: list[Unit], bar: _Progress) -> list[UnitResult]:
    out = []
    for u in units:
        bar.update(1)
        out.append(run_unit(u))
        bar.update(0, out[-1])
    return out


def _run_ray(ray, units: list[Unit], cfg: BatchConfig, bar: _Progress) -> list[UnitResult]:
    """Submit units as Ray tasks, at most ``slots`` at a time (so "running" means running), and collect
    them as they finish."""
    gpus = _gpus_per_task(ray, cfg, units)
    slots = _slots(ray, cfg, gpus)
    task = ray.remote(run_unit).options(num_cpus=cfg.cpus_per_task, num_gpus=gpus, max_retries=1)
    res = ray.cluster_resources()
    log.info("Ray: %g CPUs, %g GPUs; %d unit(s) at a time, %d CPU%s per unit", res.get("CPU", 0),
             res.get("GPU", 0), slots, cfg.cpus_per_task, f" and {gpus:g} GPU" if gpus else "")
    pending, running, results = list(units), {}, []
    try:
        while pending or running:
            while pending and len(running) < slots:
                u = pending.pop(0)
                running[task.remote(u)] = u
            bar.update(len(running))
            ready, _ = ray.wait(list(running), num_returns=1, timeout=1.0)
            for ref in ready:
                results.append(_collect(ray, ref, running.pop(ref)))
                bar.update(len(running), results[-1])
    except KeyboardInterrupt:
        _cancel(ray, list(running))
        raise
    return results


def _collect(ray, ref, unit: Unit) -> UnitResult:
    try:
        return ray.get(ref)
    except ray.exceptions.RayError as e:  # the worker died (out of memory, node lost): the task could not say
        res = UnitResult(unit.capture, unit.seed, "failed", f"Ray: {one_line(e)}")
        write_record(unit, res)
        return res


def _cancel(ray, refs: list) -> None:
    """Interrupt the running tasks (KeyboardInterrupt in each: their atomic folders clean up), then kill
    what has not stopped within 30 s."""
    for ref in refs:
        ray.cancel(ref)
    _, left = ray.wait(refs, num_returns=len(refs), timeout=30.0) if refs else ([], [])
    for ref in left:
        ray.cancel(ref, force=True)


def _gpus_per_task(ray, cfg: BatchConfig, units: list[Unit]) -> float:
    if cfg.gpus_per_task is not None:
        return cfg.gpus_per_task
    wants = any(getattr(getattr(u.config, "train", None), "device", "auto") != "cpu" for u in units)
    return 1.0 if wants and ray.cluster_resources().get("GPU", 0) >= 1 else 0.0


def _slots(ray, cfg: BatchConfig, gpus: float) -> int:
    res = ray.cluster_resources()
    n = int(res.get("CPU", 1) // cfg.cpus_per_task)
    if gpus:
        n = min(n, int(res.get("GPU", 0) // gpus))
    if n < 1:
        raise SparselfError(f"the Ray cluster ({res}) has too few resources for one unit "
                            f"({cfg.cpus_per_task} CPU, {gpus:g} GPU)")
    return min(n, cfg.workers) if cfg.workers else n


def _import_ray():
    try:
        import ray
    except ImportError:
        raise SparselfError(RAY_MISSING) from None
    return ray


@contextlib.contextmanager
def _env(**values: str) -> Iterator[None]:
    """Set environment variables for the block (what Ray's processes inherit when it starts them)."""
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def ray_session(cfg: BatchConfig, out: Path):
    """Ray for this batch: the caller's if already started (left running), a cluster at ``address``, or
    an embedded one on this machine (dashboard off, its logs kept in ``out/logs/ray``), shut down after."""
    ray = _import_ray()
    if ray.is_initialized():
        yield ray
        return
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage reports from a library call
    if cfg.address:
        ray.init(address=cfg.address, log_to_driver=False, logging_level=logging.WARNING)
        try:
            yield ray
        finally:
            ray.shutdown()
        return
    # a short temp path: Ray's socket paths must stay under ~100 characters; logs are copied out after
    tmp = tempfile.mkdtemp(prefix="sparself-ray-")
    cpus = cfg.workers * cfg.cpus_per_task if cfg.workers else os.cpu_count() or 1
    try:
        with _env(RAY_worker_niceness=os.environ.get("RAY_worker_niceness", "0")):
            # Ray niceness 15 for workers would starve the batch behind any other job on this machine;
            # the units are the user's main work, as `sparself densify` itself is
            ray.init(num_cpus=cpus, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR,
                     _temp_dir=tmp)
        try:
            yield ray
        finally:
            ray.shutdown()
    finally:
        logs = Path(tmp) / "session_latest" / "logs"
        if logs.is_dir():
            shutil.copytree(logs, out / "logs" / "ray", dirs_exist_ok=True, ignore_dangling_symlinks=True)
        shutil.rmtree(tmp, ignore_errors=True)


# ---- the batch ---------------------------------------------------------------------------------------

def run_batch(kind: str, manifest: Path, out: Path, base, cfg: BatchConfig | None = None) -> BatchResult:
    """``sparself batch KIND MANIFEST --out OUT``: every unit not done yet, then the combined report.

    base: the DensifyConfig or EvalConfig that manifest options override per capture.
    """
    cfg = cfg or BatchConfig()
    cfg.validate()
    if kind not in KINDS:
        raise SparselfError(f"unknown batch kind {kind!r}; choose one of {', '.join(KINDS)}")
    if not cfg.local:
        _import_ray()  # say how to install it before anything is written
    captures = read_manifest(Path(manifest), kind)
    out = Path(out)
    check_not_input(out, [Input("manifest", manifest)] + [Input("capture", c.path) for c in captures])
    _claim(out, kind)
    units = make_units(kind, captures, base, out, cfg.cpus_per_task)
    for u in units:  # leftovers of a batch killed with SIGKILL
        remove_stale_temps(u.out)
    done = {(u.capture, u.seed): r for u in units if (r := finished(u)) is not None}
    todo = [u for u in units if (u.capture, u.seed) not in done]
    log.info("%s: %d unit(s), %d done by an earlier run, %d to run", manifest, len(units), len(done), len(todo))
    done.update({(r.capture, r.seed): r for r in run_units(todo, cfg, out)})
    results = [done[(u.capture, u.seed)] for u in units]
    writer = _densify_report if kind == "densify" else _evaluate_report
    _publish(out, lambda tmp: writer(units, results, tmp, manifest))
    return BatchResult(kind, out, results)


def _claim(out: Path, kind: str) -> None:
    """Use ``out`` for a batch of ``kind``: a new or empty folder, or one an earlier batch of the same kind
    made (resumed). Anything else is refused: the batch never writes into a folder it does not own."""
    marker = out / "batch.json"
    if out.is_dir() and any(out.iterdir()):
        try:
            old = json.loads(marker.read_text()).get("kind")
        except (OSError, json.JSONDecodeError, AttributeError):
            raise OutputError(f"{out}: folder exists and is not a sparself batch folder; use another --out") from None
        if old != kind:
            raise OutputError(f"{out}: holds a batch {old}, not a batch {kind}; use another --out")
        return
    check_output_dir(out)  # a file there, or an unwritable parent
    out.mkdir(parents=True, exist_ok=True)
    write_marker(out)
    with atomic_file(marker) as tmp:
        tmp.write_text(json.dumps({"format": "sparself-batch", "version": 1, "kind": kind}) + "\n")


def _publish(out: Path, write) -> None:
    """Write the report into a temporary folder inside ``out`` and move each part into place (every file
    replaced whole). A ``captures`` link in it keeps figure paths valid both there and in ``out``."""
    tmp = Path(tempfile.mkdtemp(prefix=f".report.tmp-{os.getpid()}-", dir=out))
    try:
        (tmp / "captures").symlink_to(Path("..") / "captures")
        write(tmp)
        for name in ("figures", "results.json", "report.md", "report.html"):
            if (tmp / name).exists():
                if (out / name).is_dir():
                    shutil.rmtree(out / name)
                os.replace(tmp / name, out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _failures(results: list[UnitResult]) -> list[dict]:
    return [{"capture": r.capture, "seed": r.seed, "error": r.error} for r in results if r.status != "ok"]


def _densify_report(units: list[Unit], results: list[UnitResult], tmp: Path, manifest: Path) -> None:
    rows = [{**dataclasses.asdict(r), "name": u.capture, "source": str(u.source),
             "output": str(u.out.relative_to(u.logs.parent))} for u, r in zip(units, results)]
    data = {"settings": {"kind": "densify", "manifest": str(manifest), "versions": versions(),
                         "config": {u.capture: _config_json(u.config) for u in units}},
            "scenes": rows, "failures": _failures(results), "not_run": {}}
    (tmp / "results.json").write_text(json.dumps(data, indent=1))
    write_densify_report(data, tmp)


def _evaluate_report(units: list[Unit], results: list[UnitResult], tmp: Path, manifest: Path) -> None:
    """The evaluate report of all captures: each capture's seed units merged into one scene result
    (sparself's per-seed entries side by side, mean +- std over seeds), in evaluate's results shape."""
    by_capture: dict[str, list[tuple[Unit, UnitResult]]] = {}
    for u, r in zip(units, results):
        by_capture.setdefault(u.capture, []).append((u, r))
    data: dict = {"settings": {}, "not_run": {}, "scenes": [], "failures": _failures(results)}
    for name, pairs in by_capture.items():
        ok = [(u, json.loads((u.out / "results.json").read_text())) for u, r in pairs if r.status == "ok"]
        bad = [f"seed {r.seed}: {r.error}" for _, r in pairs if r.status != "ok"]
        if not ok:
            data["scenes"].append({"name": name, "source": str(pairs[0][0].source), "status": "failed",
                                   "error": "; ".join(bad)})
            continue
        if not data["settings"]:
            data["settings"], data["not_run"] = ok[0][1]["settings"], ok[0][1].get("not_run", {})
        scene = merge_seeds([(u.seed, res["scenes"][0], u.out.relative_to(u.logs.parent)) for u, res in ok])
        scene["notes"] = scene.get("notes", []) + [f"{b} (failed)" for b in bad]
        data["scenes"].append(scene)
    seeds = [u.config.first_seed for u in units]
    data["settings"].update(seeds=len(set(seeds)), batch_manifest=str(manifest))
    data["settings"].pop("first_seed", None)
    data["batch"] = {"units": [{**dataclasses.asdict(r), "output": str(u.out.relative_to(u.logs.parent))}
                               for u, r in zip(units, results)]}
    (tmp / "results.json").write_text(json.dumps(data, indent=1, allow_nan=True))
    write_report(data, tmp)


SEEDED_SECTIONS = ("view_synthesis",) + PLANNED_SECTIONS  # a scene's sections with the network's per-seed sets


def merge_seeds(parts: list[tuple[int, dict, Path]]) -> dict:
    """One capture's evaluate result from its seed units: (seed, scene result, unit folder relative to
    the report). The lowest seed's result carries the baselines and the oracle; sparself's per-seed
    entries of the others are added and its summaries (and oracle share) recomputed over all seeds."""
    parts = sorted(parts, key=lambda p: p[0])
    merged = copy.deepcopy(parts[0][1])
    merged["examples"], merged["timings"] = {}, {}
    for seed, s, rel in parts:
        if s is not parts[0][1]:
            for sec in SEEDED_SECTIONS:
                if NETWORK in s.get(sec, {}):
                    merged.setdefault(sec, {}).setdefault(NETWORK, {"per_seed": []})["per_seed"] += \
                        s[sec][NETWORK]["per_seed"]
            for r, d in s.get("densification", {}).items():
                for key in (NETWORK, NETWORK_WEIGHTED):  # a unit's weighted fit records its own chosen weight
                    if "per_seed" in d.get(key, {}):
                        m = merged.setdefault("densification", {}).setdefault(r, {})
                        if "per_seed" not in m.get(key, {}):  # absent, or the first unit's failure
                            m[key] = {"per_seed": [], "views": d[key].get("views")}
                        m[key]["per_seed"] += d[key]["per_seed"]
        for frame, imgs in s.get("examples", {}).items():
            ex = merged["examples"].setdefault(frame, {})
            for k, v in imgs.items():  # the ground truth and base fits are the same in every seed's folder
                ex.setdefault(k, str(rel / v))
        for k, v in s.get("timings", {}).items():
            merged["timings"][k] = merged["timings"].get(k, 0.0) + v
    if merged.get("camera_plot"):
        merged["camera_plot"] = str(parts[0][2] / merged["camera_plot"])
    for entry in [merged.get(sec, {}).get(NETWORK) for sec in SEEDED_SECTIONS] + \
            [d.get(k) for d in merged.get("densification", {}).values() for k in (NETWORK, NETWORK_WEIGHTED)]:
        if entry and entry.get("per_seed"):
            again = _seeded(entry["per_seed"]).to_json()  # the summary, and per group where there are two
            entry.update({k: again[k] for k in ("summary", "groups") if k in again})
    for d in merged.get("densification", {}).values():
        oracle_share(d)
    return merged


def _seeded(per_seed: list[dict]):
    """The SeededSets of per-seed records read back from results.json (to summarise them again)."""
    return SeededSets([ScoredSet([FrameScore(**f) for f in p["frames"]], p.get("seed"), p.get("views"))
                       for p in per_seed])
