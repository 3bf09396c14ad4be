"""The report's figures: bar charts and example grids (matplotlib, imported only when a figure is drawn)."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np

from sparself.capture.images import load_image


def pyplot():
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def bar_chart(path: Path, title: str, groups: list[str], series: dict[str, list], ylabel: str) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(max(5, 1.6 * len(groups) + 2), 3.6), dpi=100)
    try:
        width = 0.8 / max(len(series), 1)
        x = np.arange(len(groups))
        for k, (label, vals) in enumerate(series.items()):
            v = [np.nan if a is None else a for a in vals]
            ax.bar(x + (k - (len(series) - 1) / 2) * width, v, width, label=label)
        ax.set_xticks(x)
        ax.set_xticklabels(groups, rotation=15, fontsize=8)
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)


def image_grid(out_dir: Path, path: Path, images: dict[str, str]) -> bool:
    """Ground truth, then each prediction with its error map (|pred - truth| averaged over channels)."""
    if "ground_truth" not in images:
        return False
    gt = load_image(out_dir / images["ground_truth"], warn=False)
    preds = [(k, load_image(out_dir / v, warn=False)) for k, v in images.items() if k != "ground_truth"]
    plt = pyplot()
    n = len(preds) + 1
    fig, axes = plt.subplots(2, n, figsize=(2.2 * n, 4.6), dpi=100, squeeze=False)
    try:
        axes[0, 0].imshow(gt)
        axes[0, 0].set_title("ground truth (held out)", fontsize=7)
        axes[1, 0].axis("off")
        for k, (label, img) in enumerate(preds, start=1):
            axes[0, k].imshow(np.clip(img, 0, 1))
            err = np.abs(img - gt).mean(-1) if img.shape == gt.shape else np.zeros(gt.shape[:2])
            mse = float(np.mean((img - gt) ** 2)) if img.shape == gt.shape else float("nan")
            axes[0, k].set_title(label, fontsize=7)
            axes[1, k].imshow(err, cmap="inferno", vmin=0, vmax=0.5)
            axes[1, k].set_title(f"|error| (PSNR {-10 * np.log10(max(mse, 1e-12)):.1f})", fontsize=7)
        for a in axes.ravel():
            a.set_xticks([])
            a.set_yticks([])
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return True
