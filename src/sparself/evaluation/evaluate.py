"""Evaluation of many captures: read the manifest, run the held-out protocol (:mod:`sparself.evaluation.protocol`)
on each scene, write ``results.json`` and the report atomically into the output folder."""

from __future__ import annotations

import dataclasses
import json
import logging
import traceback
from dataclasses import replace
from pathlib import Path
from typing import Sequence

from tqdm.auto import tqdm

from sparself.capture.io import read_scene
from sparself.capture.scene import Scene
from sparself.core import metrics
from sparself.core.errors import InputError
from sparself.core.locks import output_lock
from sparself.core.outputs import Input, atomic_dir, check_not_input, check_output_dir, evaluation_inputs, work_dir
from sparself.evaluation.config import DIETNERF_NOTE, EvalConfig, eval_config
from sparself.evaluation.instruments import versions
from sparself.evaluation.protocol import evaluate_scene, name_from_source, run_name, scene_name
from sparself.evaluation.report import write_report
from sparself.evaluation.results_file import Results, Settings
from sparself.evaluation.scene_results import SceneFailure
from sparself.evaluation.split import make_split
from sparself.synthesis.train_config import TrainConfig

log = logging.getLogger(__name__)


def read_capture_list(path: Path) -> list[Path]:
    """Scene paths listed one per line (blank lines and # comments ignored; relative to the file)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: manifest not found")
    out = []
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            p = Path(line)
            out.append(p if p.is_absolute() else path.parent / p)
    if not out:
        raise InputError(f"{path}: manifest lists no scenes")
    return out


def run_evaluation(scenes: Sequence[Scene | Path], cfg: EvalConfig, out_dir: Path | None = None, **hooks) -> Results:
    """Evaluate every scene (paths are read with sparself.capture.io.read_scene); failures are recorded.

    Returns the settings, what was not run, and a record per run. hooks are passed to :func:`evaluate_scene`.
    """
    cfg.validate()
    try:
        from sparself.recon.gsplat import available as gs_available

        gs_ok, gs_why = gs_available()
    except Exception as e:
        gs_ok, gs_why = False, str(e)
    settings = {
        **dataclasses.asdict(cfg),
        "versions": versions(),
        "lpips_status": metrics.lpips_status() if cfg.lpips else "unavailable: disabled by settings",
    }
    results = Results(Settings(settings), {"dietnerf": DIETNERF_NOTE})
    if not gs_ok:
        results.not_run["gsplat"] = f"not run: {gs_why}"
    if hooks.get("reconstructors") is not None:
        settings["reconstructors"] = list(hooks["reconstructors"])
    if not gs_ok and "gsplat" in cfg.reconstructors:
        cfg = replace(cfg, reconstructors=tuple(r for r in cfg.reconstructors if r != "gsplat"))
    for item in tqdm(list(scenes), desc="scenes", disable=not cfg.progress):
        label = str(item) if not isinstance(item, Scene) else str(item.source or "scene")
        try:
            scene = item if isinstance(item, Scene) else read_scene(Path(item))
        except Exception as e:
            results.scenes.append(_failed(label, e, cfg))
            continue
        ns = sweep(scene, cfg)
        for n in ns:
            try:
                res = evaluate_scene(scene, cfg, out_dir, n_inputs=n, **hooks)
                if len(ns) < len(cfg.inputs):
                    res.notes.append(
                        f"run once for N = {', '.join(map(str, cfg.inputs))}: a capture too small for the dense "
                        "protocol has every frame not held out as its inputs, whatever N"
                    )
                results.scenes.append(res)
            except Exception as e:
                results.scenes.append(_failed(label, e, cfg, n))
    return results


def sweep(scene: Scene, cfg: EvalConfig) -> list[int]:
    """The N values a capture is run with: every one of ``cfg.inputs``, or only the largest on a capture too
    small for the dense protocol (its inputs are every frame not held out, whatever N)."""
    if len(cfg.inputs) > 1 and make_split(len(scene), cfg).kind == "sparse":
        log.info("%s: a sparse capture has the same inputs for every N: run once", scene_name(scene))
        return [max(cfg.inputs)]
    return list(cfg.inputs)


def _failed(label: str, e: Exception, cfg: EvalConfig, n_inputs: int | None = None) -> SceneFailure:
    """The record of a run that failed (the others go on)."""
    log.error("%s: evaluation failed: %s", label, e)
    capture = name_from_source(label)
    return SceneFailure(
        capture if n_inputs is None else run_name(capture, cfg, n_inputs),
        label,
        f"{type(e).__name__}: {e}",
        capture,
        n_inputs,
        traceback.format_exc(limit=5),
    )


def evaluate(
    scenes: Sequence[Scene | Path],
    out: Path,
    cfg: EvalConfig | None = None,
    *,
    overwrite: bool = False,
    resume: bool = False,
    **hooks,
) -> Results:
    """Run the protocol and write ``results.json``, ``report.md``, ``report.html`` and figures to ``out``
    (atomically: nothing is left there if it fails). Returns the results. While it runs, the networks' checkpoints
    and the fits are kept in a work folder beside ``out`` (:func:`~sparself.core.outputs.work_dir`), left there
    when the run is stopped; ``resume`` continues from them, to the same results as a run never stopped."""
    cfg = cfg or EvalConfig()
    cfg.validate()
    inputs = evaluation_inputs(scenes)
    check_output_dir(Path(out), overwrite, inputs)
    with output_lock(out), work_dir(out, resume), atomic_dir(Path(out), overwrite, inputs) as tmp:
        results = run_evaluation(scenes, cfg, tmp, **hooks)
        (tmp / "results.json").write_text(json.dumps(results.to_json(), indent=1, allow_nan=True))
        write_report(results, tmp)
    return results


def run_cli(
    scene_paths: Sequence[Path],
    out: Path,
    manifest: Path | None = None,
    *,
    quick: bool = False,
    overwrite: bool = False,
    resume: bool = False,
    train_cfg: TrainConfig | None = None,
    **given,
) -> Results:
    """What ``sparself evaluate`` does: gather scenes (arguments + manifest) and call :func:`evaluate`.

    given: :class:`EvalConfig` fields set on the command line; the others keep the defaults of
    :class:`EvalConfig` (or of :meth:`EvalConfig.quick`). train_cfg: the network's training options.
    """
    check_not_input(out, [Input("manifest", manifest)])
    paths = [Path(p) for p in scene_paths] + (read_capture_list(manifest) if manifest else [])
    if not paths:
        raise InputError("no scenes given (pass scene folders or --manifest FILE)")
    from sparself.core.progress import show_progress

    cfg = eval_config(quick=quick, train_cfg=train_cfg, **given)
    cfg = replace(cfg, progress=cfg.progress and show_progress())  # no bar fragments in a log file, none with -q
    return evaluate(paths, out, cfg, overwrite=overwrite, resume=resume)
