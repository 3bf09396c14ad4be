"""The densification table (the paper's Table 3 shape) one capture and one network seed at a time, so that
seeds and captures can run side by side on one machine (a GPU: the network, the NeRF and gsplat run there),
then merged into one report.

    python benchmarks/table3.py run ../shared/data/llff_bird --seed 0 --out out/t3/bird_s0 [--recon mpi,nerf,3dgs]
    python benchmarks/table3.py run ../shared/data/middlebury_dinoSparseRing --seeds 3 --out out/t3/dino
    python benchmarks/table3.py merge out/t3/bird_s0 out/t3/bird_s1 ... --out out/t3/report

``run`` saves ``results.json`` after the network, the baselines and each reconstructor (a run stopped by a
time limit keeps what it finished). ``merge`` groups the runs by capture, merges their seeds
(``sparself.batch.merge_seeds``: the lowest seed's run carries the baselines, N alone and the oracle) and
writes ``results.json``, ``report.md`` and ``report.html``. Every number is scored on held-out real photos
(``sparself evaluate``'s protocol and its defaults unless given here).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from pathlib import Path


def _gsplat_fit(steps: int, seed: int, wait_for: str | None = None):
    """3DGS with gsplat (CUDA) at a fixed step count, or the CPU splatting where gsplat cannot run.
    wait_for: a file whose existence says gsplat's CUDA code is built (gsplat rebuilds from scratch in every
    process that finds no build, so parallel runs must wait for one build)."""
    from sparself.recon import get_reconstructor
    from sparself.recon.gsplat import available

    if available()[0]:
        fit = get_reconstructor("gsplat")

        def fit_built(sc):
            while wait_for and not Path(wait_for).exists():
                time.sleep(1)
            return fit(sc, steps=steps, seed=seed, progress=False)

        return fit_built
    fit = get_reconstructor("splat")
    return lambda sc: fit(sc, seed=seed, progress=False)


def run(args) -> int:
    from sparself.capture.io import read_scene
    from sparself.evaluation.config import EvalConfig
    from sparself.evaluation.instruments import reconstructor, versions
    from sparself.evaluation.protocol import evaluate_scene
    from sparself.evaluation.scene_results import SceneResult

    recons = tuple(args.recon.split(","))
    cfg = EvalConfig(
        size=args.size,
        seeds=args.seeds,
        first_seed=args.seed,
        reconstructors=recons,
        densify_baselines=tuple(filter(None, args.densify_baselines.split(","))),
        baselines=tuple(args.baselines.split(",")),
        lpips=False,
        progress=False,
        max_eval=args.max_eval,
        epochs=args.epochs,
        nerf_steps=args.nerf_steps,
        **_set(args.set),
    )
    fits = {
        r: _gsplat_fit(args.gs_steps, cfg.recon_seed, args.wait_for) if r == "3dgs" else reconstructor(r, cfg)
        for r in recons
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    settings = {
        **json.loads(json.dumps(dataclasses.asdict(cfg), default=str)),
        "versions": versions(),
        "gsplat_steps": args.gs_steps,
        "lpips_status": "unavailable: disabled by settings",
    }

    def save(scene: SceneResult) -> None:
        res = {**scene.to_json(), "wall_s": time.time() - t0}
        tmp = out / "results.json.tmp"
        tmp.write_text(json.dumps({"settings": settings, "not_run": {}, "scenes": [res]}, indent=1, default=_num))
        tmp.replace(out / "results.json")
        logging.warning("%s seed %d: saved after %.0f s", scene.name, args.seed, time.time() - t0)

    res = evaluate_scene(read_scene(Path(args.scene)), cfg, None, reconstructors=fits, on_partial=save)
    save(res)
    return 0


def _set(pairs: list[str]) -> dict:
    return {k: json.loads(v) for k, v in (p.split("=", 1) for p in pairs)}


def _num(x):
    import numpy as np

    return x.item() if isinstance(x, np.generic) else str(x)


def merge(args) -> int:
    from sparself.batch import merge_seeds
    from sparself.evaluation.report import write_report
    from sparself.evaluation.results_file import Results, Settings, read_results

    runs = [read_results(Path(d) / "results.json") for d in args.runs]
    by_scene: dict[str, list] = {}
    for d, data in zip(args.runs, runs):
        s = data.scenes[0]
        by_scene.setdefault(s.name, []).append((data.settings.option("first_seed"), s, Path(d)))
    scenes = [merge_seeds(parts) for parts in by_scene.values()]
    seeds = len({p[0] for ps in by_scene.values() for p in ps})
    results = Results(Settings({**runs[0].settings.recorded, "seeds": seeds}), {}, list(scenes))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results.to_json(), indent=1, allow_nan=True))
    write_report(results, out)
    print(out / "report.md")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="one capture, one network seed")
    r.add_argument("scene")
    r.add_argument("--seed", type=int, default=0, help="the (first) network seed")
    r.add_argument("--seeds", type=int, default=1, help="network seeds run one after another in this run")
    r.add_argument("--out", required=True)
    r.add_argument("--recon", default="mpi,nerf,3dgs")
    r.add_argument("--size", type=int, default=128)
    r.add_argument("--baselines", default="nearest,blend,flow,planesweep")
    r.add_argument("--densify-baselines", default="flow")
    r.add_argument("--max-eval", type=int, default=None)
    r.add_argument("--epochs", type=int, default=None, help="network epochs (default: the network's)")
    r.add_argument("--nerf-steps", type=int, default=1000)
    r.add_argument("--gs-steps", type=int, default=3000, help="gsplat steps per fit (CUDA)")
    r.add_argument("--wait-for", default=None, help="wait for this file before the first gsplat fit")
    r.add_argument("--set", action="append", default=[], metavar="FIELD=JSON", help="any other EvalConfig field")
    m = sub.add_parser("merge", help="merge runs into one report")
    m.add_argument("runs", nargs="+")
    m.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    return run(args) if args.cmd == "run" else merge(args)


if __name__ == "__main__":
    sys.exit(main())
