"""The final evaluation behind the README's results: `python benchmarks/results/final_eval.py mpi nerf`
(writes out/final_mpi and out/final_nerf; about 25 + 5 min on 2 CPU cores)."""
import logging, sys, time
from pathlib import Path
import torch
torch.set_num_threads(1)
logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
from sparself.evaluate import EvalConfig, evaluate
root = Path(__file__).resolve().parents[2]; data = root.parent / 'shared' / 'data'
for which in sys.argv[1:]:
    if which == 'mpi':
        scenes = [data/'llff_bird', data/'middlebury_templeRing', data/'middlebury_templeSparseRing', data/'middlebury_dinoSparseRing', root/'samples'/'bird']
        cfg = EvalConfig(size=128, seeds=2, reconstructors=('mpi',), densify_baselines=('blend','flow','planesweep'), max_eval=8, progress=False)
    else:
        scenes = [data/'llff_bird']
        cfg = EvalConfig(size=96, seeds=1, reconstructors=('nerf',), densify_baselines=('flow',), max_eval=8, nerf_steps=800, progress=False)
    t = time.time()
    evaluate(scenes, root/'out'/f'final_{which}', cfg, overwrite=True)
    print('done', which, time.time() - t, flush=True)
