"""Running a batch's units: one after another in this process, or as Ray tasks on a local or remote cluster."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from tqdm.auto import tqdm

from sparself.batch_units import RAY_MISSING, BatchConfig, Unit, UnitResult, one_line, run_unit, write_record
from sparself.core.errors import SparselfError
from sparself.core.interrupts import signals_interrupt
from sparself.core.outputs import remove_stale_temps
from sparself.core.progress import show_progress

log = logging.getLogger(__name__)


class Progress:
    """One bar for the whole batch: units done / running / failed, elapsed and estimated time left."""

    def __init__(self, total: int, enabled: bool | None, kind: str = "densify") -> None:
        self.kind = kind
        self.bar = tqdm(
            total=total,
            desc="batch",
            unit="unit",
            dynamic_ncols=True,
            disable=not (show_progress() if enabled is None else enabled),
        )
        self.running = self.failed = 0

    def update(self, running: int, result: UnitResult | None = None) -> None:
        self.running = running
        if result is not None:
            self.failed += result.status != "ok"
            self.bar.update(1)
            if result.status != "ok":
                log.warning("%s failed: %s", result.label(self.kind), result.error)
        self.bar.set_postfix_str(f"done {self.bar.n - self.failed}, running {running}, failed {self.failed}")

    def close(self) -> None:
        self.bar.close()


def run_units(units: list[Unit], cfg: BatchConfig, out: Path) -> list[UnitResult]:
    """Run the units (locally or on Ray) behind one progress bar; on an interruption the running units
    are cancelled and their temporary folders removed before KeyboardInterrupt goes on up."""
    bar = Progress(len(units), cfg.progress, units[0].kind if units else "densify")
    try:
        if cfg.local:
            with signals_interrupt(reset=False):
                return run_local(units, bar)
        with ray_session(cfg, out) as ray, signals_interrupt(reset=False):  # after ray.init, which sets its own
            return run_ray(ray, units, cfg, bar)
    finally:
        bar.close()
        for u in units:  # leftovers of cancelled or killed units (their processes are gone)
            remove_stale_temps(u.out)
            remove_stale_temps(u.record)


def run_local(units: list[Unit], bar: Progress) -> list[UnitResult]:
    out = []
    for u in units:
        bar.update(1)
        out.append(run_unit(u))
        bar.update(0, out[-1])
    return out


def run_ray(ray, units: list[Unit], cfg: BatchConfig, bar: Progress) -> list[UnitResult]:
    """Submit units as Ray tasks, at most ``slots`` at a time (so "running" means running), and collect
    them as they finish."""
    gpus = gpus_per_task(ray, cfg, units)
    slots = task_slots(ray, cfg, gpus)
    task = ray.remote(run_unit).options(num_cpus=cfg.cpus_per_task, num_gpus=gpus, max_retries=1)
    res = ray.cluster_resources()
    log.info(
        "Ray: %g CPUs, %g GPUs; %d unit(s) at a time, %d CPU%s per unit",
        res.get("CPU", 0),
        res.get("GPU", 0),
        slots,
        cfg.cpus_per_task,
        f" and {gpus:g} GPU" if gpus else "",
    )
    pending, results = list(units), []
    running: dict[object, Unit] = {}  # Ray task reference -> its unit
    try:
        while pending or running:
            while pending and len(running) < slots:
                u = pending.pop(0)
                running[task.remote(u)] = u
            bar.update(len(running))
            ready, _ = ray.wait(list(running), num_returns=1, timeout=1.0)
            for ref in ready:
                results.append(collect(ray, ref, running.pop(ref)))
                bar.update(len(running), results[-1])
    except KeyboardInterrupt:
        cancel(ray, list(running))
        raise
    return results


def collect(ray, ref, unit: Unit) -> UnitResult:
    try:
        return ray.get(ref)
    except ray.exceptions.RayError as e:  # the worker died (out of memory, node lost): the task could not say
        res = UnitResult(unit.capture, unit.seed, "failed", f"Ray: {one_line(e)}")
        write_record(unit, res)
        return res


def cancel(ray, refs: list) -> None:
    """Interrupt the running tasks (KeyboardInterrupt in each: their atomic folders clean up), then kill
    what has not stopped within 30 s."""
    for ref in refs:
        ray.cancel(ref)
    _, left = ray.wait(refs, num_returns=len(refs), timeout=30.0) if refs else ([], [])
    for ref in left:
        ray.cancel(ref, force=True)


def gpus_per_task(ray, cfg: BatchConfig, units: list[Unit]) -> float:
    if cfg.gpus_per_task is not None:
        return cfg.gpus_per_task
    wants = any(getattr(getattr(u.config, "train", None), "device", "auto") != "cpu" for u in units)
    return 1.0 if wants and ray.cluster_resources().get("GPU", 0) >= 1 else 0.0


def task_slots(ray, cfg: BatchConfig, gpus: float) -> int:
    res = ray.cluster_resources()
    n = int(res.get("CPU", 1) // cfg.cpus_per_task)
    if gpus:
        n = min(n, int(res.get("GPU", 0) // gpus))
    if n < 1:
        raise SparselfError(
            f"the Ray cluster ({res}) has too few resources for one unit ({cfg.cpus_per_task} CPU, {gpus:g} GPU)"
        )
    return min(n, cfg.workers) if cfg.workers else n


def import_ray():
    try:
        import ray
    except ImportError:
        raise SparselfError(RAY_MISSING) from None
    return ray


@contextlib.contextmanager
def env(**values: str) -> Iterator[None]:
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
    ray = import_ray()
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
        with env(RAY_worker_niceness=os.environ.get("RAY_worker_niceness", "0")):
            # Ray niceness 15 for workers would starve the batch behind any other job on this machine;
            # the units are the user's main work, as `sparself densify` itself is
            ray.init(
                num_cpus=cpus, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR, _temp_dir=tmp
            )
        try:
            yield ray
        finally:
            ray.shutdown()
    finally:
        logs = Path(tmp) / "session_latest" / "logs"
        if logs.is_dir():
            shutil.copytree(logs, out / "logs" / "ray", dirs_exist_ok=True, ignore_dangling_symlinks=True)
        shutil.rmtree(tmp, ignore_errors=True)
