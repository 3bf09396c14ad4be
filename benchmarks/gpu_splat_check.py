"""Device check: our CPU Gaussian splatting (sparself.recon.splat) against gsplat's ``rasterization`` on the
same Gaussians. Needs CUDA and the gsplat package; elsewhere it says so and exits 0.

    python benchmarks/gpu_splat_check.py                 # 3000 Gaussians, 128 x 96, SH degree 1
    python benchmarks/gpu_splat_check.py --n 20000 --width 256 --height 192

Prints, per case, the max / mean absolute difference of the RGB images and alpha maps, and the time of a
render (gsplat on the GPU, median of 20 after a warm-up; ours on the CPU, median of 3). Differences
expected: float32 rounding, and footprint edges where the two rules for a Gaussian's extent differ
(ours: where alpha can reach 1/255; gsplat: 3 sigma, or its opacity-aware extent in newer versions),
at most about 1/255 per Gaussian there.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

import torch  # noqa: E402

from sparself.capture.scene import Camera  # noqa: E402
from sparself.core.geometry import Pose  # noqa: E402
from sparself.recon.splat import Gaussians, project, rasterize  # noqa: E402


def _gaussians(n: int, seed: int, opaque: bool) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([1.2, 0.9, 0.8]) + torch.tensor([0.0, 0.0, 4.0])
    return Gaussians(
        means,
        torch.randn(n, 4, generator=g),
        torch.randn(n, 3, generator=g) * 0.4 - 3.2,
        torch.randn(n, generator=g) + (3.0 if opaque else 0.0),
        torch.randn(n, 4, 3, generator=g) * 0.5,
    )


def _ours(g: Gaussians, pose: Pose, cam: Camera, bg: torch.Tensor):
    p = project(
        g,
        torch.tensor(pose.w2c(), dtype=torch.float32),
        torch.tensor(cam.K, dtype=torch.float32),
        cam.width,
        cam.height,
        1,
    )
    return rasterize(p, cam.width, cam.height, bg)


def _theirs(gsplat, g: Gaussians, pose: Pose, cam: Camera, bg: torch.Tensor):
    dev = torch.device("cuda")
    img, alpha, _ = gsplat.rasterization(
        means=g.means.to(dev),
        quats=g.quats.to(dev),
        scales=torch.exp(g.log_scales).to(dev),
        opacities=torch.sigmoid(g.opacity_logits).to(dev),
        colors=g.sh.to(dev),
        viewmats=torch.tensor(pose.w2c(), dtype=torch.float32, device=dev)[None],
        Ks=torch.tensor(cam.K, dtype=torch.float32, device=dev)[None],
        width=cam.width,
        height=cam.height,
        sh_degree=1,
        backgrounds=bg.to(dev)[None],
        packed=False,
        eps2d=0.3,
        near_plane=0.01,
    )
    return img[0], alpha[0, ..., 0]


def _time(fn, reps: int, sync=None) -> float:
    out = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        if sync:
            sync()
        out.append(time.perf_counter() - t)
    return statistics.median(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=3000)
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    try:
        import gsplat
    except Exception as e:  # ImportError, or a CUDA extension that fails to build or load
        print(f"needs CUDA + gsplat: gsplat is not importable ({type(e).__name__}: {e})")
        return 0
    if not torch.cuda.is_available():
        print("needs CUDA + gsplat: no CUDA device")
        return 0
    torch.set_num_threads(args.threads)
    print(
        f"gsplat {getattr(gsplat, '__version__', '?')}, torch {torch.__version__}, "
        f"{torch.cuda.get_device_name()}, {args.n} Gaussians, {args.width} x {args.height}, SH degree 1"
    )
    cam = Camera.pinhole(args.width, args.height, 0.95 * args.width)
    a = np.radians(8.0)
    turned = Pose.from_center(np.array([np.cos(a / 2), 0.0, np.sin(a / 2), 0.0]), np.array([0.3, -0.1, -0.2]))
    front = Pose.from_center(np.array([1.0, 0, 0, 0]), np.zeros(3))
    bg = torch.tensor([0.1, 0.2, 0.3])
    print("| case | max abs diff RGB | mean abs diff RGB | max abs diff alpha | gsplat (ms, GPU) | ours (ms, CPU) |")
    print("|---|---|---|---|---|---|")
    worst = 0.0
    for name, pose, opaque in (("front, translucent", front, False), ("turned, opaque", turned, True)):
        g = _gaussians(args.n, 0, opaque)
        with torch.no_grad():
            mine, mine_a = _ours(g, pose, cam, bg)
            theirs, theirs_a = _theirs(gsplat, g, pose, cam, bg)
            d = (mine - theirs.cpu()).abs()
            da = (mine_a - theirs_a.cpu()).abs()
            t_gs = _time(lambda: _theirs(gsplat, g, pose, cam, bg), 20, torch.cuda.synchronize)
            t_me = _time(lambda: _ours(g, pose, cam, bg), 3)
        worst = max(worst, float(d.max()))
        print(
            f"| {name} | {float(d.max()):.2e} | {float(d.mean()):.2e} | {float(da.max()):.2e} | "
            f"{1e3 * t_gs:.2f} | {1e3 * t_me:.1f} |",
            flush=True,
        )
    print(f"\nlargest RGB difference {worst:.3g} ({worst * 255:.2f} / 255)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
