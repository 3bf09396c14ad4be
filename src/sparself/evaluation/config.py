"""The evaluation's options (:class:`EvalConfig`) and what ``--quick`` changes."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Literal

from sparself.core.errors import ConfigError
from sparself.core.options import check_choices, option
from sparself.synthesis.train_config import TrainConfig

DIETNERF_NOTE = "not run: DietNeRF needs CLIP weights that cannot be fetched here (no internet)"


PlannedSection = Literal["midpoints", "extrapolations"]
Gap = Literal["other", "own"]  # where the self-check measures a view's gain (evaluation.folds)
PixelWeights = Literal["auto", "choose", "confidence", "uniform"]  # per-pixel weights of the self-check's views
KeepRule = Literal["each", "together"]  # which views a self-check fold keeps
# results of the planned views that have a real photo
PLANNED_SECTIONS: tuple[PlannedSection, ...] = ("midpoints", "extrapolations")


VALIDATION_EVERY = 5  # every 5th interior input view is held back to choose the synthetic-frame weight

# what --quick changes
QUICK: dict[str, Any] = dict(size=64, seeds=1, nerf_steps=300, max_eval=6, densify_baselines=("blend",), epochs=30)


@dataclass
class EvalConfig:
    """Every setting of an evaluation run (all recorded in the results; each field's help is its
    documentation, and ``sparself evaluate --help`` shows them). ``train``: the network's training options
    (its seed, size and epochs are set by the evaluation)."""

    size: int = option(128, "longer image side in pixels for every step (images are resized once, on load)")
    inputs: tuple[int, ...] = option(
        (25,),
        "N, the number of sparse input views taken from a dense capture; several, comma-separated (9,12,25): one "
        "run, the same held-out frames and extrapolation margin for every N, results per N",
    )
    extrapolation_margin: int | None = option(
        None,
        "capture frames kept beyond the first and last input of a dense capture (never inputs): their real "
        "photos score extrapolated views; auto: one input spacing, at least holdout_every + 1 so held-out frames "
        "lie beyond both ends; 0: the inputs span the whole capture",
    )
    holdout_every: int = option(8, "hold out every k-th interior frame of a dense capture")
    sparse_holdout_every: int = option(2, "the same for captures too small for the dense protocol")
    n_mid: int = option(8, "planned midpoints used for densification")
    n_extra: int = option(2, "planned extrapolated poses used for densification")
    seeds: int = option(3, "network seeds, reported as mean ± std")
    first_seed: int = option(
        0,
        "the first network seed: seeds are first_seed .. first_seed + seeds - 1 (`sparself "
        "batch evaluate` runs one seed per task)",
    )
    reconstructors: tuple[str, ...] = option(
        ("mpi", "nerf"), "reconstructors, comma-separated: mpi,nerf,gsplat,3dgs", flag="--recon"
    )
    baselines: tuple[str, ...] = option(
        ("nearest", "blend", "flow", "planesweep"), "view-synthesis baselines scored on held-out poses"
    )
    densify_baselines: tuple[str, ...] = option(
        ("blend", "flow", "planesweep"), "baselines whose synthesized views are also used for densification"
    )
    epochs: int | None = option(None, "network training epochs (auto: the network's)")
    nerf_steps: int = option(1000, "NeRF optimisation steps per fit")
    splat_steps_per_view: int | None = option(
        None,
        "CPU 3DGS optimisation steps per training view (a short run); auto: the reconstructor's own "
        "(1500 steps, at least 60 per view)",
    )
    splat_far_reach: tuple[float, ...] = option(
        (1.0, 5.0),
        "CPU 3DGS: how many times further than the sparse points' far depth its random starting points reach, "
        "on captures whose depth bounds come from their points; several, comma-separated: per capture, the one "
        f"whose fit on the inputs minus every {VALIDATION_EVERY}th interior one renders those held-back inputs "
        "best (the first on ties), for every row (measured: 5x on dinoSparseRing and samples/bird without its "
        "bounds, 1x on templeSparseRing, see docs/results.md); one: that reach everywhere",
    )
    recon_seed: int = option(
        0, "seed of the reconstructors: every row of network seed k, N alone included, is fitted with recon_seed + k"
    )
    max_eval: int | None = option(None, "score at most this many held-out frames per scene (evenly chosen; auto: all)")
    checked: bool = option(
        True,
        "'N + sparself, checked': each reconstructor also refitted on what `densify --recon R` writes for it "
        "(views planned as densify --plan auto plans them, fixed, and kept only where they raise R's PSNR on "
        "held-back inputs)",
    )
    check_plan: Literal["auto", "weak", "paper"] = option(
        "auto",
        "where the checked row's views go: where R is weak, or the paper's plan (the planned poses); auto: as "
        "densify --plan auto (the paper's for the NeRF)",
    )
    check_gain_gap: Gap = option(
        "own",
        "where the checked row's self-check measures a view: outside its own gap, or inside it (densify --gain-gap)",
    )
    check_pixel_weights: PixelWeights = option(
        "auto", "per-pixel weights of the checked row's views (densify --pixel-weights; auto: as densify's)"
    )
    check_keep: KeepRule = option("each", "which views a fold of the checked row's self-check keeps (densify --keep)")
    check_gap_trend: bool = option(
        False,
        "the checked row's self-check keeps views between the inputs only where their gain's trend with the "
        "gap's width says they pay in the final fit (densify --gap-trend)",
    )
    check_confirm: bool | None = option(
        None,
        "the checked row's self-check tests its kept views on the input photos no fold held back before keeping "
        "them (densify --confirm; auto: for the 3DGS and the NeRF)",
    )
    check_confirm_prune: bool | None = option(
        None,
        "the checked row's self-check drops the kept views beside a confirmation photo that loses too much and "
        "tests the rest once more (densify --confirm-prune; auto: for the 3DGS)",
    )
    check_loss_within_gain: bool = option(
        True,
        "the checked row's confirmation fails when one of its photos loses more than they gain on the mean "
        "(as densify --no-loss-within-gain)",
    )
    check_max_photo_loss: float | None = option(
        1.0,
        "dB a held-back photo of the checked row's self-check may lose before a fold's views go (densify "
        "--max-photo-loss)",
    )
    check_ends_context: bool | None = option(
        None,
        "the checked row's self-check judges the views past the ends beside the views between the inputs "
        "(densify --ends-context; auto: for the 3DGS)",
    )
    check_fill_control: bool | None = option(
        None,
        "the checked row's self-check keeps a view only where it beats content-free fills at its pose (flat, "
        "two of noise) at its held-back photos (densify --fill-control; auto: for the MPI)",
    )
    check_fix_rounds: int = option(
        1,
        "rounds of render -> fix -> refit in the checked row's self-check, each kept while it raises the folds' "
        "held-back photos (densify --fix-rounds)",
    )
    check_steps: int = option(300, "optimisation steps of each self-check fit of the checked row (densify's default)")
    check_size: int = option(64, "long side in px of the checked row's self-check fits (densify's default)")
    oracle: bool = option(True, "the oracle densification: N + the real photos at the planned poses")
    weighted: bool = option(
        True,
        "'N + sparself, weighted': each reconstructor also refitted on N + the network's "
        "views with their confidence maps as per-pixel loss weights and a synthetic-frame "
        "weight chosen on input views only",
    )
    synthetic_weights: tuple[float, ...] = option(
        (0.25, 0.5, 1.0),
        "synthetic-frame loss weights tried for 'N + sparself, weighted': each is fitted on the "
        f"inputs minus every {VALIDATION_EVERY}th interior one (+ the first seed's views), the best PSNR on those "
        "held-back inputs wins (one fit per weight and reconstructor, plus one refit per seed)",
    )
    examples: int = option(1, "held-out frames per scene saved as image grids for the report")
    lpips: bool = option(True, "score LPIPS besides PSNR and SSIM (when its weights are found on this machine)")
    points: Literal["inputs", "capture"] = option(
        "inputs",
        "the inputs' sparse points (3DGS initial Gaussians, NeRF's scene box, the depth "
        "range of scenes without bounds): 'inputs' triangulates them from the N inputs' photos at their "
        "known poses (the capture's own points, made from every photo, held-out ones included, are "
        "dropped); 'capture' keeps the capture's points (as runs before this option)",
    )
    progress: bool = option(True, "progress bars", cli=False)
    train: TrainConfig = field(default_factory=TrainConfig)

    def __post_init__(self) -> None:
        # one N (an int, as before several were allowed) or several, kept in ascending order
        n = (self.inputs,) if isinstance(self.inputs, int) else tuple(self.inputs)
        self.inputs = tuple(sorted(set(n)))

    def validate(self) -> None:
        if self.size < 8:
            raise ConfigError(f"size must be at least 8 pixels, got {self.size}")
        if not self.inputs or min(self.inputs) < 3:
            raise ConfigError(f"inputs must be at least 3, got {','.join(map(str, self.inputs)) or 'none'}")
        if self.holdout_every < 2 or self.sparse_holdout_every < 2:
            raise ConfigError("holdout_every and sparse_holdout_every must be at least 2")
        if self.seeds < 1:
            raise ConfigError(f"seeds must be at least 1, got {self.seeds}")
        if not self.splat_far_reach or min(self.splat_far_reach) < 1:
            raise ConfigError(f"splat_far_reach must be one or more reaches >= 1, got {self.splat_far_reach}")
        if self.splat_steps_per_view is not None and self.splat_steps_per_view < 1:
            raise ConfigError(f"splat_steps_per_view must be at least 1, got {self.splat_steps_per_view}")
        if self.check_steps < 1 or self.check_size < 8:
            raise ConfigError(
                f"check_steps must be >= 1 and check_size >= 8, got {self.check_steps}, {self.check_size}"
            )
        if self.check_fix_rounds < 1:
            raise ConfigError(f"check_fix_rounds must be at least 1, got {self.check_fix_rounds}")
        if self.first_seed < 0:
            raise ConfigError(f"first_seed must not be negative, got {self.first_seed}")
        if self.extrapolation_margin is not None and self.extrapolation_margin < 0:
            raise ConfigError(f"extrapolation_margin must not be negative, got {self.extrapolation_margin}")
        check_choices(self)
        if self.weighted and (not self.synthetic_weights or min(self.synthetic_weights) < 0):
            raise ConfigError(f"synthetic_weights must be one or more weights >= 0, got {self.synthetic_weights}")

    @property
    def seed_list(self) -> list[int]:
        """The run's seeds, first_seed .. first_seed + seeds - 1: each a network seed and, through
        :func:`~sparself.evaluation.instruments.fit_seed`, the reconstruction seed of every row of that seed."""
        return list(range(self.first_seed, self.first_seed + self.seeds))

    @classmethod
    def quick(cls, **kw) -> "EvalConfig":
        """Minutes, not hours, on 2 CPU cores: 64 px, 1 seed, 30 network epochs (seconds at 64 px; 3 epochs
        left the network under-trained: 1 dB less on llff_bird's reconstructions at 9 inputs),
        a short NeRF, at most 6 scored frames, one baseline densified."""
        base = dict(QUICK)
        base.update(kw)
        return cls(**base)


def eval_config(*, quick: bool = False, train_cfg: TrainConfig | None = None, **given) -> EvalConfig:
    """The command line's EvalConfig: the fields given (None: not given) over the defaults of
    :class:`EvalConfig` or of :meth:`EvalConfig.quick`; train_cfg: the network's training options."""
    cfg = EvalConfig.quick() if quick else EvalConfig()
    return replace(cfg, **{k: v for k, v in given.items() if v is not None}, train=train_cfg or cfg.train)
