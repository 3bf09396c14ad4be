#!/usr/bin/env python3
"""Rebuild samples/bird/ from the llff_bird capture: 49 evenly spaced views at half resolution.

Usage (from the repository root, with shared/ beside it):
    python samples/make_bird_sample.py [--src ../shared/data/llff_bird] [--out samples/bird]

Views np.round(np.linspace(0, 183, 49)) are kept (every ~3.8th of 184), so an evaluation can use every
other one (25 views) as the sparse input and the 24 in between as held-out ground truth. Images are
downscaled 2x with an area filter (544x960 -> 272x480, W x H) and saved as JPEG quality 90 under their
original names; poses_bounds.npy keeps those rows unchanged except hwf, scaled to the new size.
Deterministic: the same source gives byte-identical output.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np
from PIL import Image

N_VIEWS = 49
FACTOR = 2
QUALITY = 90


def views(n_total: int, n_keep: int = N_VIEWS) -> np.ndarray:
    """Indices (into sorted file names) of the kept views."""
    return np.round(np.linspace(0, n_total - 1, n_keep)).astype(int)


def make(src: Path, out: Path) -> None:
    names = sorted(p.name for p in (src / "images").iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    pb = np.load(src / "poses_bounds.npy")
    if pb.shape != (len(names), 17):
        sys.exit(f"{src}: poses_bounds.npy has shape {pb.shape}, expected ({len(names)}, 17)")
    keep = views(len(names))
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "images").mkdir(parents=True)
    rows = pb[keep].copy()
    for k, i in enumerate(keep):
        with Image.open(src / "images" / names[i]) as im:
            im = im.convert("RGB")
            w, h = im.size
            small = im.resize((w // FACTOR, h // FACTOR), Image.Resampling.BOX)
            small.save(tmp / "images" / names[i], quality=QUALITY, optimize=True)
        H, W, f = rows[k, 4], rows[k, 9], rows[k, 14]
        if (int(H), int(W)) != (h, w):
            sys.exit(f"{src}: hwf of {names[i]} says {int(W)}x{int(H)}, image is {w}x{h}")
        rows[k, 4], rows[k, 9], rows[k, 14] = H / FACTOR, W / FACTOR, f / FACTOR
    np.save(tmp / "poses_bounds.npy", rows)
    # Check: every kept row equals the original except the scaled hwf column.
    orig = pb[keep].reshape(-1, 17)
    cols = [c for c in range(17) if c not in (4, 9, 14)]
    assert np.array_equal(np.load(tmp / "poses_bounds.npy")[:, cols], orig[:, cols])
    if out.exists():
        for p in ("images", "poses_bounds.npy"):
            q = out / p
            shutil.rmtree(q) if q.is_dir() else q.unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    shutil.move(str(tmp / "images"), str(out / "images"))
    shutil.move(str(tmp / "poses_bounds.npy"), str(out / "poses_bounds.npy"))
    shutil.rmtree(tmp)
    print(f"wrote {len(keep)} views to {out}: {', '.join(names[i] for i in keep[:3])}, ...")


def main() -> None:
    root = Path(__file__).resolve().parents[1]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", type=Path, default=root.parent / "shared" / "data" / "llff_bird")
    ap.add_argument("--out", type=Path, default=root / "samples" / "bird")
    a = ap.parse_args()
    make(a.src, a.out)


if __name__ == "__main__":
    main()
