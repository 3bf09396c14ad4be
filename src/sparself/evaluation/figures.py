"""The report's figures: bar charts and example grids (matplotlib, imported only when a figure is drawn)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

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


def sweep_plot(path: Path, title: str, panels: dict[str, dict[str, tuple[list[int], list[float]]]]) -> None:
    """PSNR against N, one panel per reconstructor: panels = {reconstructor: {row label: (Ns, PSNRs)}}."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels) + 0.6, 3.2), dpi=100, squeeze=False)
    try:
        for ax, (recon, rows) in zip(axes[0], panels.items()):
            for label, (ns, vals) in rows.items():
                ax.plot(ns, vals, marker="o", label=label)
            ax.set_xticks(sorted({n for ns, _ in rows.values() for n in ns}))
            ax.set_xlabel("N (input views)")
            ax.set_ylabel("PSNR (dB) on held-out photos")
            ax.set_title(recon, fontsize=9)
            ax.legend(fontsize=7)
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)


GRID_COLUMNS = 6  # images per row of an example grid before it wraps


def grid_rows(labels: list[str], recons: list[str], columns: int = GRID_COLUMNS) -> list[tuple[str, list[str]]]:
    """The example grid's rows: (title, labels), the view synthesis methods first, then one row per
    reconstructor (its renders are labelled "<reconstructor> <k> views (...)"), each cut into rows of at most
    ``columns`` images."""
    groups: dict[str, list[str]] = {}
    for label in labels:
        head = label.split(" ", 1)[0]
        key = head if head in recons and " views (" in label else "view synthesis"
        groups.setdefault(key, []).append(label)
    order = ["view synthesis"] + [r for r in recons if r in groups]
    return [(k, groups[k][i : i + columns]) for k in order if k in groups for i in range(0, len(groups[k]), columns)]


def image_grid(out_dir: Path, path: Path, images: dict[str, str], recons: Sequence[str] = ()) -> bool:
    """Rows of (ground truth, predictions), each prediction over its error map (|pred - truth| averaged over
    channels): the view synthesis methods, then one row per reconstructor (:func:`grid_rows`)."""
    if "ground_truth" not in images:
        return False
    gt = load_image(out_dir / images["ground_truth"], warn=False)
    rows = grid_rows([k for k in images if k != "ground_truth"], list(recons))
    plt = pyplot()
    n = 1 + max((len(labels) for _, labels in rows), default=0)
    fig, axes = plt.subplots(2 * max(len(rows), 1), n, figsize=(2.2 * n, 2.3 * 2 * max(len(rows), 1)), dpi=100)
    axes = np.asarray(axes).reshape(2 * max(len(rows), 1), n)
    try:
        for a in axes.ravel():
            a.axis("off")
        for k, (title, labels) in enumerate(rows):
            top, bottom = axes[2 * k], axes[2 * k + 1]
            top[0].imshow(gt)
            top[0].set_title(f"ground truth (held out)\n{title}", fontsize=7)
            for j, label in enumerate(labels, start=1):
                _prediction(top[j], bottom[j], label, load_image(out_dir / images[label], warn=False), gt)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return True


def _prediction(ax, ax_err, label: str, img: np.ndarray, gt: np.ndarray) -> None:
    """One prediction and, below it, its error map titled with its PSNR."""
    ax.imshow(np.clip(img, 0, 1))
    ax.set_title(label, fontsize=7)
    same = img.shape == gt.shape
    err = np.abs(img - gt).mean(-1) if same else np.zeros(gt.shape[:2])
    mse = float(np.mean((img - gt) ** 2)) if same else float("nan")
    ax_err.imshow(err, cmap="inferno", vmin=0, vmax=0.5)
    ax_err.set_title(f"|error| (PSNR {-10 * np.log10(max(mse, 1e-12)):.1f})", fontsize=7)
