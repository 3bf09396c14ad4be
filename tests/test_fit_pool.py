"""Fits run side by side in worker processes give exactly the renderers fitted one after the other here,
and a pool left by an exception stops its workers."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from planescene import DEPTH, plane_scene
from sparself.evaluation.selfcheck import SelfCheckConfig, check_workers
from sparself.recon.pool import FitPool, Fitter

SPLAT = dict(steps=20, init_points=150, max_gaussians=300, progress=False, seed=1, min_steps_per_view=0)


def _scenes():
    out = []
    for k in range(3):
        sc = plane_scene(xs=tuple(0.1 * i + 0.05 * k for i in range(3)))
        rng = np.random.default_rng(k)
        sc.points = np.stack([rng.uniform(-0.7, 0.9, 200), rng.uniform(-0.5, 0.5, 200), np.full(200, DEPTH)], 1)
        out.append(sc)
    return out


def test_workers_fit_exactly_what_this_process_fits(compiled_splat):
    scenes = _scenes()
    a = [Fitter("splat", SPLAT)(sc) for sc in scenes]  # one after the other, here
    with FitPool(2) as two:
        b = Fitter("splat", SPLAT).many(scenes, two)
    for sc, r, q in zip(scenes, a, b):
        cam, pose = sc.cameras[1], sc.frames[1].pose
        np.testing.assert_array_equal(r.render(pose, cam), q.render(pose, cam))
    assert len({float(r.render(scenes[0].frames[0].pose, scenes[0].cameras[1]).mean()) for r in a}) == 3


def test_workers_ignore_stop_signals_and_an_exception_in_the_block_kills_them_at_once():
    with pytest.raises(KeyboardInterrupt):
        with FitPool(2) as pool:
            assert pool._pool is not None
            pool._pool.submit(time.sleep, 60)  # a long fit running when Ctrl-C comes
            time.sleep(0.5)
            procs = list(pool._pool._processes.values())
            for q in procs:  # a signal to the whole process group: the workers leave it to this process
                os.kill(q.pid, signal.SIGTERM)
            time.sleep(0.5)
            assert all(q.is_alive() for q in procs)
            raise KeyboardInterrupt
    deadline = time.time() + 10
    while any(p.is_alive() for p in procs) and time.time() < deadline:
        time.sleep(0.1)
    assert procs and not any(p.is_alive() for p in procs)


def test_the_self_check_runs_fits_side_by_side_only_for_the_one_core_cpu_3dgs():
    assert check_workers(SelfCheckConfig(recon="mpi")) == 1 and check_workers(SelfCheckConfig(recon="nerf")) == 1
    assert check_workers(SelfCheckConfig(recon="mpi", check_workers=3)) == 3
    assert 1 <= check_workers(SelfCheckConfig(recon="3dgs")) <= 4
    assert check_workers(SelfCheckConfig(recon="3dgs", check_steps=30)) == 1  # shorter than starting a worker


def test_tasks_in_turns_share_the_workers_never_work_here_at_once_and_fit_what_they_fit_alone():
    scenes = _scenes()
    fitter = Fitter("splat", SPLAT)
    alone = [fitter(sc) for sc in scenes]
    events: list[str] = []
    here = []  # tasks working in this process right now

    def task(k: int, pool: FitPool):
        def run():
            here.append(k)
            assert here == [k]  # holding the turn: no other task works here
            events.append(f"start {k}")
            here.remove(k)
            (r,) = fitter.many([scenes[k]], pool)  # a lone fit: it goes to a worker, the turn to another task
            here.append(k)
            assert here == [k]
            events.append(f"done {k}")
            here.remove(k)
            return r

        return run

    with FitPool(2) as pool:
        got = pool.in_turns([task(k, pool) for k in range(3)])
    assert events.index("start 1") < events.index("done 0")  # the second task's fit was given while the first's ran
    for sc, r, q in zip(scenes, alone, got):
        cam, pose = sc.cameras[1], sc.frames[1].pose
        np.testing.assert_array_equal(r.render(pose, cam), q.render(pose, cam))
    with FitPool(1) as one:  # one worker: the tasks run one after the other, here
        events.clear()
        one.in_turns([task(k, one) for k in range(2)])
    assert events == ["start 0", "done 0", "start 1", "done 1"]


def test_a_failing_task_in_turns_raises_and_the_pool_stops_the_others():
    def failing():
        raise ValueError("broken scene")

    def slow(pool: FitPool):
        return lambda: pool.run([("splat", _scenes()[0], {**SPLAT, "steps": 5000})])

    t = time.time()
    with pytest.raises(ValueError, match="broken scene"):
        with FitPool(2) as pool:
            pool.in_turns([failing, slow(pool)])
    assert time.time() - t < 60  # the slow fit (about 160 s alone on 2 cores) was not waited for
