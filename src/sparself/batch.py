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

import copy
import dataclasses
import json
import logging
import os
import shutil
import tempfile
from dataclasses import fields
from pathlib import Path

from sparself.batch_ray import import_ray, run_units
from sparself.batch_units import (
    KINDS,
    BatchConfig,
    BatchResult,
    Capture,
    Unit,
    UnitResult,
    config_json,
    finished,
    make_units,
)
from sparself.core.errors import InputError, OutputError, SparselfError
from sparself.core.names import check_names
from sparself.core.outputs import (
    Input,
    atomic_file,
    check_not_input,
    check_output_dir,
    remove_stale_temps,
    write_marker,
)
from sparself.evaluation.batch_report import write_densify_report
from sparself.evaluation.config import PLANNED_SECTIONS, EvalConfig
from sparself.evaluation.evaluate import read_capture_list
from sparself.evaluation.instruments import versions
from sparself.evaluation.protocol import name_from_source
from sparself.evaluation.report import write_report
from sparself.evaluation.report_context import safe_name
from sparself.evaluation.results import NETWORK, ReconResult, Row, SeededSets
from sparself.evaluation.results_file import (
    DensifyBatchResults,
    Results,
    UnitFailure,
    UnitRecord,
    read_results,
)
from sparself.evaluation.scene_results import SceneFailure, SceneResult, Timings
from sparself.synthesis.plan import PlanConfig
from sparself.synthesis.train_config import TrainConfig

log = logging.getLogger(__name__)


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
        return _named(path, [Capture("", p) for p in read_capture_list(path)])
    data = _load_structured(path)
    defaults = data.get("defaults", {}) if isinstance(data, dict) else {}
    entries = data.get("captures") if isinstance(data, dict) else data
    if not isinstance(entries, list) or not entries or not isinstance(defaults, dict):
        raise InputError(f'{path}: expected a list of captures, or {{"defaults": {{...}}, "captures": [...]}}')
    allowed = option_names(kind)
    caps = []
    for k, e in enumerate(entries):
        e = {"path": e} if isinstance(e, str) else e
        if not isinstance(e, dict) or not isinstance(e.get("path"), str):
            raise InputError(f'{path}: capture {k + 1} needs a "path"')
        opts = {**defaults, **{k2: v for k2, v in e.items() if k2 not in ("path", "name")}}
        unknown = sorted(set(opts) - allowed)
        if unknown:
            raise InputError(
                f"{path}: capture {k + 1}: unknown option(s) {', '.join(unknown)} (known: {', '.join(sorted(allowed))})"
            )
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
            raise InputError(
                f"{manifest}: two captures are named {c.name!r} ({seen[c.name]}, {c.path}); "
                'give one a "name" (JSON manifest)'
            )
        seen[c.name] = c.path
    # each name is a folder under captures/: never '.', '..' or empty, nor two that differ only in case
    check_names([c.name for c in caps], manifest, what="capture name")
    return caps


# ---- units -------------------------------------------------------------------------------------------


# ---- running the units -------------------------------------------------------------------------------


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
        import_ray()  # say how to install it before anything is written
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


def _failures(results: list[UnitResult]) -> list[UnitFailure]:
    return [UnitFailure(r.capture, r.seed, r.error) for r in results if r.status != "ok"]


def _densify_report(units: list[Unit], results: list[UnitResult], tmp: Path, manifest: Path) -> None:
    rows: list[UnitRecord] = [
        dataclasses.replace(
            r,
            name=u.capture,
            source=str(u.source),
            output=str(u.out.relative_to(u.logs.parent)),
        )
        for u, r in zip(units, results)
    ]
    config = {u.capture: config_json(u.config) for u in units}
    data = DensifyBatchResults(str(manifest), versions(), config, rows, _failures(results))
    (tmp / "results.json").write_text(json.dumps(data.to_json(), indent=1))
    write_densify_report(data, tmp)


def _evaluate_report(units: list[Unit], results: list[UnitResult], tmp: Path, manifest: Path) -> None:
    """The evaluate report of all captures: each capture's seed units merged into one scene result
    (sparself's per-seed entries side by side, mean +- std over seeds), in evaluate's results shape."""
    by_capture: dict[str, list[tuple[Unit, UnitResult]]] = {}
    for u, r in zip(units, results):
        by_capture.setdefault(u.capture, []).append((u, r))
    data = Results(failures=_failures(results))
    for name, pairs in by_capture.items():
        ok = [(u, read_results(u.out / "results.json")) for u, r in pairs if r.status == "ok"]
        bad = [f"seed {r.seed}: {r.error}" for _, r in pairs if r.status != "ok"]
        if not ok:
            data.scenes.append(SceneFailure(name, str(pairs[0][0].source), "; ".join(bad)))
            continue
        if not data.settings.recorded:
            data.settings, data.not_run = ok[0][1].settings, ok[0][1].not_run
        scene = merge_seeds([(u.seed, _ran(res, u.out), u.out.relative_to(u.logs.parent)) for u, res in ok])
        scene.notes += [f"{b} (failed)" for b in bad]
        data.scenes.append(scene)
    seeds = [u.seed for u in units]  # each evaluate unit runs its config's first_seed
    data.settings = data.settings.for_batch(len(set(seeds)), str(manifest))
    data.units = [dataclasses.replace(r, output=str(u.out.relative_to(u.logs.parent))) for u, r in zip(units, results)]
    (tmp / "results.json").write_text(json.dumps(data.to_json(), indent=1, allow_nan=True))
    write_report(data, tmp)


def _ran(res: Results, folder: Path) -> SceneResult:
    """The one run of a finished unit's results."""
    scene = res.scenes[0] if res.scenes else None
    if not isinstance(scene, SceneResult):
        raise InputError(f"{folder / 'results.json'}: holds no finished run; remove {folder} to redo it")
    return scene


def _network_sets(s: SceneResult) -> list[dict[str, Row]]:
    """A scene's sections that hold the network's per-seed sets: the held-out poses and the planned ones."""
    return [s.synthesis.held_out] + [s.synthesis.planned(sec) for sec in PLANNED_SECTIONS]


def _add_seeds(rows: dict[str, Row], name: str, more: SeededSets) -> None:
    """Append ``more``'s seeds to ``rows[name]`` (made where absent, or replacing the first unit's failure)."""
    row = rows.get(name)
    if not isinstance(row, SeededSets):
        row = rows[name] = SeededSets()
    row.per_seed += more.per_seed


def merge_seeds(parts: list[tuple[int, SceneResult, Path]]) -> SceneResult:
    """One capture's evaluate result from its seed units: (seed, scene result, unit folder relative to
    the report). The lowest seed's result carries the view-synthesis baselines; the per-seed sets of the
    others (sparself's views and every reconstruction row, N alone and the oracle included, each fitted with
    its seed's reconstruction seed and with its own decision) are added and their summaries (and the oracle
    shares) recomputed over all seeds."""
    parts = sorted(parts, key=lambda p: p[0])
    merged = copy.deepcopy(parts[0][1])
    merged.examples, merged.timings = {}, Timings()
    for seed, s, rel in parts:
        if s is not parts[0][1]:
            for mine, theirs in zip(_network_sets(merged), _network_sets(s)):
                net = theirs.get(NETWORK)
                if isinstance(net, SeededSets):
                    _add_seeds(mine, NETWORK, net)
            for r, d in s.densification.items():
                for name, row in d.rows.items():
                    if isinstance(row, SeededSets):
                        _add_seeds(merged.densification.setdefault(r, ReconResult()).rows, name, row)
        for frame, imgs in s.examples.items():
            ex = merged.examples.setdefault(frame, {})
            for k, v in imgs.items():  # the ground truth and base fits are the same in every seed's folder
                ex.setdefault(k, str(rel / v))
        merged.timings = merged.timings.plus(s.timings)
    if merged.camera_plot:
        merged.camera_plot = str(parts[0][2] / merged.camera_plot)
    seeded = [sec[NETWORK] for sec in _network_sets(merged) if NETWORK in sec]
    seeded += [row for d in merged.densification.values() for row in d.rows.values()]
    for row in seeded:
        if isinstance(row, SeededSets) and row.per_seed:
            row.summarized = True  # summarised again over all seeds
    for d in merged.densification.values():
        d.check_instrument()
    return merged
