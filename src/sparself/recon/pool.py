"""Several fits at once. The CPU 3DGS uses one core per fit, so on a machine with more cores independent fits
run in worker processes, one per core; a pool of one worker fits in this process, one scene after the
other (the plain path, and the reference the other must equal: each fit is seeded and single-threaded).
Independent tasks that each wait for fits in turn (the protocol's seeds' self-checks) share the workers through
:meth:`FitPool.in_turns`, so that no task's lone fit leaves a worker idle."""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence, TypeVar

from sparself.capture.scene import Scene
from sparself.core.content import digest, keep, kept
from sparself.core.outputs import current_work
from sparself.recon import Renderer, backend, get_reconstructor

log = logging.getLogger(__name__)
T = TypeVar("T")


def _ignore_interrupts() -> None:
    # Ctrl-C, `kill -TERM -PGID` and a closed terminal reach the whole process group: the parent alone decides,
    # stops its workers itself (SIGKILL) and reports "interrupted" without the workers' tracebacks
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)


def _fit(name: str, scene: Scene, cfg: dict[str, Any]) -> Renderer:
    return get_reconstructor(name)(scene, **cfg)


class FitPool:
    """``with FitPool(workers) as pool: pool.fit("3dgs", scenes, seed=0)`` -> one renderer per scene.

    workers > 1 starts that many processes (spawned: a fresh interpreter, no forked torch threads) when the
    block is entered; leaving it by an exception (Ctrl-C included) stops them at once. A renderer comes back
    pickled, so a reconstructor fitted this way must be picklable (the CPU 3DGS is)."""

    def __init__(self, workers: int = 1) -> None:
        self.workers = max(1, int(workers))
        self._pool: ProcessPoolExecutor | None = None
        self._turn: threading.Lock | None = None  # held by the in_turns thread working here, if any

    def __enter__(self) -> "FitPool":
        if self.workers > 1:
            ctx = multiprocessing.get_context("spawn")
            self._pool = ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_ignore_interrupts)
        return self

    def __exit__(self, kind, value, tb) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        running = list(getattr(pool, "_processes", {}).values())  # private, but the only handle on them
        pool.shutdown(wait=kind is None, cancel_futures=True)
        if kind is not None:
            for p in running:
                p.kill()

    def fit(self, name: str, scenes: list[Scene], **cfg) -> list[Renderer]:
        """Fit reconstructor ``name`` with keyword settings ``cfg`` on each scene; in order."""
        return self.run([(name, sc, cfg) for sc in scenes])

    def run(self, jobs: list[tuple[str, Scene, dict[str, Any]]]) -> list[Renderer]:
        """Fit each (reconstructor, scene, settings); in order. Within :meth:`in_turns` even a lone fit goes to
        a worker, and the calling thread gives up its turn until its fits are back."""
        turn = self._turn
        if self._pool is None or (len(jobs) < 2 and turn is None):
            return [_fit(*job) for job in jobs]
        futures: list[Future] = [self._pool.submit(_fit, *job) for job in jobs]
        if turn is not None:
            turn.release()
            try:
                wait(futures)
            finally:
                turn.acquire()
        return [f.result() for f in futures]

    def in_turns(self, tasks: Sequence[Callable[[], T]]) -> list[T]:
        """Each task's result, in order. With workers, the tasks run in threads that take turns at this
        process's own work: a thread works only while it holds the turn and hands it on while it waits for its
        fits, so the workers get fits from every task (no batch leaves a worker idle while another task has fits
        to give) and no two tasks compute here at once. Fits are seeded, so the results are those of the tasks
        run one after the other, which is what a pool of one worker does."""
        if self._pool is None or len(tasks) < 2:
            return [task() for task in tasks]
        turn = self._turn = threading.Lock()

        def taking_turns(task: Callable[[], T]) -> T:
            with turn:
                return task()

        threads = ThreadPoolExecutor(len(tasks), thread_name_prefix="fit-turns")
        try:
            return [f.result() for f in [threads.submit(taking_turns, t) for t in tasks]]
        finally:
            # after an error the pool's exit stops the workers, which ends the waiting threads: no wait here
            threads.shutdown(wait=False, cancel_futures=True)
            self._turn = None


MAX_WORKERS = 4  # fits at once at most: the protocol's and the self-check's batches hold up to 6


def side_by_side(name: str) -> int:
    """How many fits of reconstructor ``name`` pay to run at once here: one per core (at most MAX_WORKERS)
    for the CPU 3DGS, which fits on one core; 1 for the others (they use every core, or the GPU)."""
    if backend(name) != "splat":
        return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return max(1, min(cores, MAX_WORKERS))


@dataclass(frozen=True)
class Fitter:
    """A reconstructor with its settings: ``fitter(scene)`` fits one scene here; ``fitter.many(scenes)``
    fits several, side by side where that pays (:func:`side_by_side`)."""

    name: str
    settings: dict[str, Any] = field(default_factory=dict)

    def __call__(self, scene: Scene) -> Renderer:
        return self.many([scene])[0]

    @property
    def seeded(self) -> bool:
        """Whether its fits depend on a seed (an MPI's do not)."""
        return "seed" in self.settings

    def with_seed(self, seed: int) -> "Fitter":
        """The same fitter with reconstruction seed ``seed`` (itself when it takes none)."""
        return self.with_settings(seed=seed) if self.seeded else self

    def many(self, scenes: list[Scene], pool: FitPool | None = None, seeds: list[int] | None = None) -> list[Renderer]:
        """One renderer per scene, in order (scene k fitted with seed ``seeds[k]`` when given); run by ``pool``,
        else by a pool opened for these fits. Inside a command's work folder
        (:func:`~sparself.core.outputs.current_work`) the fits are kept there, and those kept read back
        (:class:`FitStore`)."""
        each = [self] * len(scenes) if seeds is None else [self.with_seed(s) for s in seeds]
        return fit_all(each, scenes, pool)

    def with_settings(self, **settings: Any) -> "Fitter":
        """The same reconstructor with ``settings`` replacing or adding to its own."""
        return replace(self, settings={**self.settings, **settings})


def fit_all(fitters: list[Fitter], scenes: list[Scene], pool: FitPool | None = None) -> list[Renderer]:
    """Scene k fitted by ``fitters[k]``, in order, as :meth:`Fitter.many` fits them: by ``pool`` (else a pool
    opened for these fits), kept in and read back from a command's work folder."""
    work = current_work()
    if work is not None:
        return FitStore(work / "fits").fitted(fitters, scenes, pool)
    return _fitted(fitters, scenes, pool)


def _fitted(fitters: list[Fitter], scenes: list[Scene], pool: FitPool | None) -> list[Renderer]:
    """Scene k fitted by ``fitters[k]``, in order, by ``pool`` or by a pool opened for these fits."""
    jobs = [(f.name, sc, f.settings) for sc, f in zip(scenes, fitters, strict=True)]
    if pool is not None:
        return pool.run(jobs)
    if not jobs:
        return []
    with FitPool(min(side_by_side(fitters[0].name), len(jobs))) as own:
        return own.run(jobs)


@dataclass(frozen=True)
class FitStore:
    """Fits kept on disk in ``folder``, each under the digest of its reconstructor, settings and scene
    (:func:`~sparself.core.content.digest`), so that work stopped and started again fits only what it had not
    fitted yet. The fits are seeded: a kept fit is the one the same job would make again."""

    folder: Path

    def fitted(self, fitters: list[Fitter], scenes: list[Scene], pool: FitPool | None = None) -> list[Renderer]:
        """Scene k fitted by ``fitters[k]``, in order: the fits found here read back, the others fitted (by
        ``pool``) and kept here as they come (a renderer that cannot be pickled is fitted again next time)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        paths = [self.folder / f"{_key(f, sc)}.pkl" for f, sc in zip(fitters, scenes, strict=True)]
        found: list[Renderer | None] = [kept(p) for p in paths]
        todo = [k for k, r in enumerate(found) if r is None]
        if len(todo) < len(found):
            log.info("%d of %d fits read back from %s", len(found) - len(todo), len(found), self.folder)
        new = dict(zip(todo, _fitted([fitters[k] for k in todo], [scenes[k] for k in todo], pool)))
        for k, r in new.items():
            keep(paths[k], r)
        return [new[k] if r is None else r for k, r in enumerate(found)]


def _key(fitter: Fitter, scene: Scene) -> str:
    """What a fit is kept under: its reconstructor, its settings (less the progress bar, which changes nothing
    fitted) and its scene."""
    return digest((fitter.name, {k: v for k, v in fitter.settings.items() if k != "progress"}, scene))
