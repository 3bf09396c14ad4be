"""One capture's evaluation in progress (:class:`SceneEval`): the split, the inputs, the planned and held-out
frames, and the scoring of a render against a held-out photo, whose pixels are decoded only there."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from sparself.capture.images import save_image
from sparself.capture.scene import Frame, Scene
from sparself.core.geometry import at_poses
from sparself.evaluation.config import EvalConfig
from sparself.evaluation.instruments import (
    SynthFn,
    load_truth,
    score,
)
from sparself.evaluation.report_context import safe_name as _safe
from sparself.evaluation.results import (
    FrameScore,
    ScoredSet,
)
from sparself.evaluation.scene_results import SceneResult
from sparself.evaluation.split import HeldOutSplit
from sparself.evaluation.weighting import ValidationViews


@dataclass
class SceneEval:
    """One scene's evaluation as its named steps fill it in: the split, the inputs and planned poses, the
    images each method synthesized at the planned poses, and the run's results (``result``)."""

    name: str
    cfg: EvalConfig
    full: Scene
    split: HeldOutSplit
    scored: list[int]  # held-out frames that are scored
    inputs: Scene
    planned: list[Frame]
    mid_truth: dict[int, int]  # planned pose k -> the real frame at it (dense: midpoints and extrapolations)
    result: SceneResult
    out_dir: Path | None = None
    ex_dir: Path | None = None
    net_planned: list[np.ndarray] = field(default_factory=list)  # per seed
    net_conf: list[np.ndarray | None] = field(default_factory=list)  # their confidence (T, H, W), per seed
    net_synths: list[SynthFn] = field(default_factory=list)  # per seed: the network, kept for the self-check
    net_targets: list[tuple[np.ndarray, np.ndarray | None]] = field(default_factory=list)  # per seed: at the targets
    validation: ValidationViews | None = None  # made once per scene, shared by every reconstructor
    baseline_planned: dict[str, np.ndarray] = field(default_factory=dict)
    on_partial: Callable[[SceneResult], None] | None = None  # called with ``result`` after each finished step

    def partial(self) -> None:
        if self.on_partial is not None:
            self.on_partial(self.result)

    @property
    def targets(self) -> list[Frame]:
        """The scored held-out frames as poses only (what synthesizers and renderers see)."""
        return [pose_only(self.full.frames[i]) for i in self.scored]

    @property
    def mid_targets(self) -> list[int]:
        return list(self.mid_truth.values())

    def at_views(self, views: list[Frame]) -> np.ndarray:
        """(scored,) bool: which scored held-out frames lie at the pose of one of ``views``
        (:func:`~sparself.core.geometry.at_poses`, on the inputs' spacing). There a densified row measures the
        views themselves more than what they add to the reconstruction at other poses."""
        return at_poses([f.pose for f in self.targets], [f.pose for f in views], [f.pose for f in self.inputs.frames])

    def score(
        self,
        images: np.ndarray,
        label: str,
        idx: list[int],
        *,
        held_out: bool = True,
        seed: int | None = None,
        views: int | None = None,
        example: bool = True,
    ) -> ScoredSet:
        """Score ``images`` against the real photos of frames ``idx``; for held-out frames among the
        examples (unless ``example`` is False), also save the images (and the ground truth once) for the
        report."""
        rows = []
        for k, i in enumerate(idx):
            frame = self.full.frames[i]
            truth = load_truth(frame, self.full.image_size(i))
            sc = score(images[k], truth, self.cfg.lpips)
            rows.append(FrameScore(frame.name, i, sc.psnr, sc.ssim, sc.lpips, group=self.split.group(i)))
            if held_out and example and self.ex_dir is not None and i in self.scored[: self.cfg.examples]:
                self._save_example(frame.name, label, images[k], truth)
        return ScoredSet(rows, seed=seed, views=views)

    def _save_example(self, frame: str, label: str, image: np.ndarray, truth: np.ndarray) -> None:
        assert self.ex_dir is not None and self.out_dir is not None  # examples are saved into an output folder
        d = self.ex_dir / _safe(frame)
        d.mkdir(exist_ok=True)
        if not (d / "ground_truth.png").exists():
            save_image(d / "ground_truth.png", truth)
        save_image(d / f"{_safe(label)}.png", image)
        ex = self.result.examples.setdefault(frame, {})
        ex["ground_truth"] = str((d / "ground_truth.png").relative_to(self.out_dir))
        ex[label] = str((d / f"{_safe(label)}.png").relative_to(self.out_dir))


def pose_only(f: Frame, **kw) -> Frame:
    """A copy of f with no pixels attached: what synthesizers and renderers may see of a held-out frame."""
    return replace(f, path=None, image=None, **kw)
