"""NeRF before a far background: do more real photos help it (the oracle >= N instrument check)?

    python benchmarks/nerf_far_background.py               # 400 steps at 40 x 30 px, about a minute
    python benchmarks/nerf_far_background.py --steps 1000 --size 64

A synthetic forward-facing capture with exact images: 17 cameras on a gently curved line looking down +z
at two textured cards (z = 2 and, partly hidden behind it, z = 3) before a textured background at z = 100;
sparse points on all three, and
the capture's bounds reaching 121 (as a phone video's). NeRF is fitted on 5 of the cameras (N) and on
those + 4 real views between them (the oracle), and scored on 4 held-out cameras. Prints one row each, with
the sampling range and the radius of the unit ball the NeRF chose.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from sparself.capture.scene import Camera, Frame, Scene  # noqa: E402
from sparself.core.geometry import Pose  # noqa: E402
from sparself.recon.nerf import fit, pixel_rays  # noqa: E402

BACKGROUND = 100.0
HELD, INPUTS, BETWEEN = [3, 7, 11, 13], [0, 4, 8, 12, 16], [2, 6, 10, 14]


def texture(x: np.ndarray, y: np.ndarray, freq: float) -> np.ndarray:
    return np.stack(
        [
            0.5 + 0.4 * np.sin(freq * x + 0.3),
            0.5 + 0.4 * np.cos(0.8 * freq * y - 0.5),
            0.5 + 0.4 * np.sin(0.6 * freq * (x + y)),
        ],
        -1,
    )


# (depth, x centre, half width, half height, texture frequency): a card, a second one partly behind it
CARDS = ((2.0, -0.15, 0.35, 0.3, 9.0), (3.0, 0.45, 0.45, 0.45, 13.0))


def render(pose: Pose, cam: Camera) -> np.ndarray:
    """The nearest card a ray meets, else the background: exact, by ray casting (occlusion included)."""
    o, d = pixel_rays(pose, cam)
    q = o + ((BACKGROUND - o[:, 2]) / d[:, 2])[:, None] * d
    img = texture(q[:, 0], q[:, 1], 0.08)
    for z, cx, hw, hh, freq in CARDS[::-1]:  # far to near: a nearer card paints over
        p = o + ((z - o[:, 2]) / d[:, 2])[:, None] * d
        hit = (np.abs(p[:, 0] - cx) < hw) & (np.abs(p[:, 1]) < hh)
        img = np.where(hit[:, None], texture(p[:, 0], p[:, 1], freq), img)
    return img.reshape(cam.height, cam.width, 3).astype(np.float32)


def capture(size: int) -> tuple[Camera, list[Frame], np.ndarray]:
    cam = Camera.pinhole(size, size * 3 // 4, 0.9 * size)
    frames = []
    for k, x in enumerate(np.linspace(-0.4, 0.4, 17)):
        pose = Pose.from_center(np.array([1.0, 0, 0, 0]), np.array([x, 0.05 * np.sin(3 * x), 0.0]))
        frames.append(Frame(f"f{k}", pose, 1, float(k), None, render(pose, cam)))
    rng = np.random.default_rng(0)
    cards = [
        np.c_[rng.uniform(cx - hw, cx + hw, 150), rng.uniform(-hh, hh, 150), np.full(150, z)]
        for z, cx, hw, hh, _ in CARDS
    ]
    far = np.c_[rng.uniform(-40, 40, (200, 2)), np.full(200, BACKGROUND)]
    return cam, frames, np.concatenate(cards + [far])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--size", type=int, default=40)
    args = ap.parse_args()
    cam, frames, pts = capture(args.size)
    print(
        "| fitted on | views | held-out PSNR (dB) | near | far | ball radius | seconds |\n|---|---|---|---|---|---|---|"
    )
    for name, idx in (("N", INPUTS), ("N + real (oracle)", INPUTS + BETWEEN)):
        t = time.perf_counter()
        scene = Scene({1: cam}, [frames[i] for i in sorted(idx)], points=pts, bounds=(1.0, 1.21 * BACKGROUND))
        r = fit(scene, steps=args.steps, levels=(16, 32, 64), hidden=32, progress=False, seed=0, threads=1)
        psnr = np.mean([-10 * np.log10(np.mean((r.render(frames[i].pose, cam) - frames[i].image) ** 2)) for i in HELD])
        print(
            f"| {name} | {len(idx)} | {psnr:.2f} | {r.near:.2f} | {r.far:.1f} | {r.radius:.2f} | "
            f"{time.perf_counter() - t:.0f} |"
        )


if __name__ == "__main__":
    main()
