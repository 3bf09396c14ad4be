"""What a densified scene carries beyond its frames, so that trainers never test on a synthesized view.

* **The split** (:class:`DenseSplit`). Val/test = the real photos the user held out, else the images that
  position-based loaders test: every 8th of all names in the written order, from the first, always real
  photos (below). Every synthesized frame is in train. Written as ``transforms.json`` lists, COLMAP-side
  list files and ``sparself.json``.
* **Order that position-based loaders cannot get wrong.** gsplat (``test_every=8``), NeRF's ``llffhold=8``,
  3DGS' ``--eval`` and nerfstudio's ``interval`` mode test the images at sorted positions 0, 8, 16, ...
  :func:`safe_order` keeps index order but moves a synthesized frame that would land on such a position
  behind the next real photo; names get a rank prefix (``0007_novel_0003.50.jpg``) so that sorting by
  name gives exactly that order, for any index (negative ones included).
* **Downscaled copies** ``images_2/4/8`` at ``(w // f, h // f)``: nerfstudio's default ``floor`` rounding
  and gsplat's ``cam.width // factor``; LLFF reads whatever size it finds and scales the focal by 1/f.
* **Masks** ``masks/<stem>.png`` (and ``masks_<f>``): each view's confidence (:func:`write_masks`), read back
  by every reader as the frames' ``mask`` (:func:`checked_mask`, :func:`read_masks_beside`).
"""

from __future__ import annotations

import json
import logging
import re
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import ClassVar, Sequence

import numpy as np
from PIL import Image

from sparself.capture.images import load_image, read_mask, resize_image, save_image
from sparself.capture.scene import Scene
from sparself.core.errors import InputError

log = logging.getLogger(__name__)

EVERY = 8  # the hold-out period of gsplat, NeRF/LLFF, 3DGS and nerfstudio's interval mode
FACTORS = (2, 4, 8)
SPARSELF_JSON = "sparself.json"
FORMAT, VERSION = "sparself-scene", 1
MASKS = "masks"  # nerfstudio's per-frame mask folder (mask_path); masks_<f> beside images_<f>
MASK_FLOOR = 0.2  # confidence below which a mask pixel is 0, which nerfstudio ignores (it reads any other as valid)
LIST_FILES = {"train": "train_list.txt", "val": "val_list.txt", "test": "test_list.txt"}  # nerfstudio colmap
_JPEG = (".jpg", ".jpeg")
_RANKED = re.compile(r"^\d{4,}_")


@dataclass(frozen=True)
class ViewCheck:
    """One planned view in the self-check: its planned name and index, its validation gain (dB of PSNR on the
    held-back input photos nearest to it, fit with the synthesized views minus fit without; None: no fold of
    the check could measure it, and it was not kept), and whether it was kept."""

    name: str
    index: float
    gain: float | None
    kept: bool


@dataclass(frozen=True)
class FixerCheck:
    """The fixer's test on the held-back input photos (``sparself.json``, in ``selfcheck``): mean PSNR of the
    network's views, of the render of the fit without those photos, and of the fixer's merge of the two
    (each photo fixed by a fixer trained on the other held-back photos); used: the merge beat both."""

    held_back: tuple[str, ...]
    psnr_view: float
    psnr_render: float
    psnr_fixed: float
    used: bool

    @classmethod
    def from_json(cls, doc: dict) -> "FixerCheck":
        return cls(
            held_back=tuple(map(str, doc["held_back"])),
            psnr_view=float(doc["psnr_view"]),
            psnr_render=float(doc["psnr_render"]),
            psnr_fixed=float(doc["psnr_fixed"]),
            used=bool(doc["used"]),
        )


@dataclass(frozen=True)
class GapTrend:
    """How the interior views' gain changes with the width of the gap they fill (``sparself.json``, in
    ``selfcheck``): mean dB gain at the held-back photos in gaps two inputs wide (the own-gap folds) and three
    wide (the gap-trend fold), and that gain extrapolated to the final fit's gaps, one wide; interior_kept:
    whether the interior views could be kept (the extrapolated gain is above the check's minimum)."""

    gain_two_wide: float
    gain_three_wide: float
    gain_one_wide: float
    interior_kept: bool

    @classmethod
    def from_json(cls, doc: dict) -> "GapTrend":
        return cls(
            gain_two_wide=float(doc["gain_two_wide"]),
            gain_three_wide=float(doc["gain_three_wide"]),
            gain_one_wide=float(doc["gain_one_wide"]),
            interior_kept=bool(doc["interior_kept"]),
        )


@dataclass(frozen=True)
class Confirmation:
    """The kept views tested together on the input photos the check's folds never hold back (``sparself.json``,
    in ``selfcheck``): those photos, each photo's dB change from the fit without views to the fit with the kept
    views (synthesized without the held-back photos), and whether that confirmed them. When a photo lost too
    much with every kept view, ``dropped`` names the views beside it that were dropped before the test that
    ``gains`` records, and ``gains_before`` holds the first test's changes (both empty: tested once)."""

    photos: tuple[str, ...]
    gains: tuple[float, ...]
    confirmed: bool
    dropped: tuple[str, ...] = ()
    gains_before: tuple[float, ...] = ()

    @classmethod
    def from_json(cls, doc: dict) -> "Confirmation":
        return cls(
            tuple(map(str, doc["photos"])),
            tuple(map(float, doc["gains"])),
            bool(doc["confirmed"]),
            tuple(map(str, doc.get("dropped", ()))),
            tuple(map(float, doc.get("gains_before", ()))),
        )


@dataclass(frozen=True)
class FillControl:
    """The kept views against content-free fills at their poses (``sparself.json``, in ``selfcheck``): the
    scored photos of the folds that kept views, their PSNR fitted with those views, with flat fills of the
    views' mean colours in their place and with two draws of uniform noise there (the same poses and weights),
    and the views dropped because they did not beat the fills there."""

    photos: tuple[str, ...]
    psnr_views: tuple[float, ...]
    psnr_flat: tuple[float, ...]
    psnr_noise: tuple[tuple[float, float], ...]
    dropped: tuple[str, ...] = ()

    @classmethod
    def from_json(cls, doc: dict) -> "FillControl":
        return cls(
            tuple(map(str, doc["photos"])),
            tuple(map(float, doc["psnr_views"])),
            tuple(map(float, doc["psnr_flat"])),
            tuple((float(a), float(b)) for a, b in doc["psnr_noise"]),
            tuple(map(str, doc.get("dropped", ()))),
        )


@dataclass(frozen=True)
class FixRound:
    """One later round of render -> fix -> refit in the self-check (``sparself.json``, in ``selfcheck``): the
    fixer's test at the held-back photos with the renders of the folds' fits *with* the previous round's
    views, the folds' mean PSNR at their scored photos fitted with the previous round's views and with this
    round's (None: not fitted, the fixer was not used), and whether the round was kept (a clear gain)."""

    fixer: FixerCheck
    psnr_before: float
    psnr_after: float | None
    kept: bool

    @classmethod
    def from_json(cls, doc: dict) -> "FixRound":
        after = doc.get("psnr_after")
        return cls(FixerCheck.from_json(doc["fixer"]), float(doc["psnr_before"]), _opt_float(after), bool(doc["kept"]))


@dataclass(frozen=True)
class SelfCheck:
    """The densify self-check's decision and the numbers it was made on (``sparself.json``, key ``selfcheck``).

    recon: the reconstructor the views were checked with; plan: how the poses were planned (weak, paper);
    validation: the held-back input photos scored, fold after fold; psnr_without: their mean PSNR fitted
    without synthesized views; psnr_by_weight: (synthetic-frame weight, mean PSNR) with every measured view
    (each fold's fits with its own views); psnr_kept: with the kept views only, as the folds kept them before
    the confirmation dropped any (None: none kept); weight: the chosen synthetic-frame weight (None: no view
    kept); views: every planned view; reason: the decision in
    words; fixer: the fixer's test (None: not tried); psnr_other_seed: the held-back photos' mean PSNR fitted
    without views at a second seed (None: not fitted), which bounds how much the fit's seed alone moves them;
    gap_trend: the interior views' gain against the width of their gap (None: not measured); confirmation: the
    kept views' test on photos no fold held back (None: not run); pixel_weights: how the views' pixels were
    weighted (confidence, uniform; None: not checked); psnr_by_pixel_weights: (pixel weights, mean PSNR at the
    best synthetic-frame weight) for each one tried when the check chose between them (empty: not chosen);
    rounds: the later rounds of render -> fix -> refit tried (empty: one round); far_reach: how many times past
    the sparse points' far depth the CPU 3DGS's fits started their random Gaussians, where it was chosen (None:
    not chosen), and psnr_by_far_reach: (reach, mean PSNR of the held-back photos) for each one tried;
    fill_control: the kept views against content-free fills at their poses (None: not run)."""

    KEY: ClassVar[str] = "selfcheck"  # its key in sparself.json and in an evaluation's per-seed records

    recon: str
    plan: str
    validation: tuple[str, ...]
    psnr_without: float
    psnr_by_weight: tuple[tuple[float, float], ...]
    psnr_kept: float | None
    weight: float | None
    views: tuple[ViewCheck, ...]
    reason: str
    fixer: FixerCheck | None = None
    psnr_other_seed: float | None = None
    gap_trend: GapTrend | None = None
    confirmation: Confirmation | None = None
    pixel_weights: str | None = None
    psnr_by_pixel_weights: tuple[tuple[str, float], ...] = ()
    rounds: tuple[FixRound, ...] = ()
    far_reach: float | None = None
    psnr_by_far_reach: tuple[tuple[float, float], ...] = ()
    fill_control: FillControl | None = None

    @property
    def kept(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.views if v.kept)

    def to_json(self) -> dict:
        doc = asdict(self)
        doc["psnr_by_weight"] = [{"weight": w, "psnr": p} for w, p in self.psnr_by_weight]
        doc["psnr_by_pixel_weights"] = [{"pixel_weights": m, "psnr": p} for m, p in self.psnr_by_pixel_weights]
        doc["psnr_by_far_reach"] = [{"far_reach": r, "psnr": p} for r, p in self.psnr_by_far_reach]
        return doc

    @classmethod
    def from_json(cls, doc: dict) -> "SelfCheck":
        return cls(
            recon=str(doc["recon"]),
            plan=str(doc["plan"]),
            validation=tuple(map(str, doc["validation"])),
            psnr_without=float(doc["psnr_without"]),
            psnr_by_weight=tuple((float(d["weight"]), float(d["psnr"])) for d in doc["psnr_by_weight"]),
            psnr_kept=_opt_float(doc.get("psnr_kept")),
            weight=_opt_float(doc.get("weight")),
            views=tuple(
                ViewCheck(str(v["name"]), float(v["index"]), _opt_float(v.get("gain")), bool(v["kept"]))
                for v in doc["views"]
            ),
            reason=str(doc["reason"]),
            fixer=FixerCheck.from_json(doc["fixer"]) if doc.get("fixer") else None,
            psnr_other_seed=_opt_float(doc.get("psnr_other_seed")),
            gap_trend=GapTrend.from_json(doc["gap_trend"]) if doc.get("gap_trend") else None,
            confirmation=Confirmation.from_json(doc["confirmation"]) if doc.get("confirmation") else None,
            pixel_weights=None if doc.get("pixel_weights") is None else str(doc["pixel_weights"]),
            psnr_by_pixel_weights=tuple(
                (str(d["pixel_weights"]), float(d["psnr"])) for d in doc.get("psnr_by_pixel_weights", ())
            ),
            rounds=tuple(FixRound.from_json(d) for d in doc.get("rounds", ())),
            far_reach=_opt_float(doc.get("far_reach")),
            psnr_by_far_reach=tuple(
                (float(d["far_reach"]), float(d["psnr"])) for d in doc.get("psnr_by_far_reach", ())
            ),
            fill_control=FillControl.from_json(doc["fill_control"]) if doc.get("fill_control") else None,
        )


def _opt_float(value) -> float | None:
    return None if value is None else float(value)


@dataclass(frozen=True)
class MadeFrom:
    """The photos a synthesized view was made from: those warped into it, and the sequence the network's
    LSTM read before it (every source photo: each one informs every view)."""

    warped: tuple[str, ...]
    sequence: tuple[str, ...]


@dataclass(frozen=True)
class DenseInfo:
    """Where a dense scene came from and what to write with it.

    holdout: names of real frames held out (they become val/test); empty = the real photos at the positions
    position-based loaders test (:func:`positional_test`).
    downscale: write ``images_2/4/8`` copies (False for large scenes).
    test_split: False = every photo fed training and synthesis: no val/test split is written.
    made_from: the photos that fed each synthesized view, by its name (written to sparself.json).
    selfcheck: the densify self-check's decision; with it ``sparself.json`` is written even when no
    synthesized view was kept.
    """

    run: str | None = None
    plan: str | None = None
    holdout: tuple[str, ...] = ()
    downscale: bool = True
    test_split: bool = True
    made_from: dict[str, MadeFrom] = field(default_factory=dict)
    selfcheck: SelfCheck | None = None


@dataclass(frozen=True)
class DenseSplit:
    """Image names per split (as written in ``images/``) and the rule that chose val/test."""

    train: tuple[str, ...]
    val: tuple[str, ...]
    test: tuple[str, ...]
    rule: str
    positional_safe: bool = True  # every 8th sorted position holds a real photo


def n_test_positions(n: int, every: int = EVERY) -> int:
    """How many of n sorted images a position-based loader tests: positions 0, every, 2 every, ..."""
    return -(-n // every)


def safe_order(synthetic: Sequence[bool], every: int = EVERY) -> list[int] | None:
    """A written order (a permutation of the frames, given in index order) that puts a real frame at every
    position ``p % every == 0``; None when there are too few real frames for that.

    It follows index order and departs from it only where it must: a synthesized frame due at a test
    position waits behind the next real one, and a real frame is kept back for a later test position
    when the remaining real frames would otherwise run short. Reals and synthesized frames each keep
    their own relative order."""
    n = len(synthetic)
    real = [i for i in range(n) if not synthetic[i]]
    synth = [i for i in range(n) if synthetic[i]]
    if len(real) < n_test_positions(n, every):
        return None
    out: list[int] = []
    r = s = 0
    for p in range(n):
        tests_after = n_test_positions(n, every) - (p // every + 1)
        real_next = s == len(synth) or (r < len(real) and real[r] < synth[s])
        spare_real = len(real) - r - 1 >= tests_after
        if p % every == 0 or (real_next and spare_real) or s == len(synth):
            out.append(real[r])
            r += 1
        else:
            out.append(synth[s])
            s += 1
    return out


def positional_test(frames: Sequence) -> list[str] | None:
    """Names of the frames (real and synthesized, any order; each with ``index`` and ``synthetic``) that
    position-based loaders will test once written: every EVERY-th of all images in :func:`safe_order`
    (real photos only), None when there are too few real photos for that. Known before any view is
    synthesized, so that these photos can be kept out of training and synthesis."""
    by_index = sorted(frames, key=lambda f: f.index)
    order = safe_order([f.synthetic for f in by_index])
    return None if order is None else [by_index[order[p]].name for p in range(0, len(order), EVERY)]


def rank_names(names: Sequence[str], exts: Sequence[str]) -> list[str]:
    """``0007_<stem><ext>``: a zero-padded rank prefix, so that names sort in the given order. Names that
    all carry such a prefix already (a dense scene written again) lose the old one first."""
    width = max(4, len(str(len(names) - 1)))
    stems = [str(Path(n).with_suffix("")).replace("/", "_") for n in names]
    if stems and all(_RANKED.match(st) for st in stems):
        stems = [_RANKED.sub("", st, count=1) for st in stems]
    return [f"{k:0{width}d}_{st}{e}" for k, (st, e) in enumerate(zip(stems, exts))]


def llff_ext(name: str) -> str:
    """The extension a real photo is written with: NeRF's loader lists only ``JPG``/``jpg``/``png`` files,
    so ``.jpeg`` becomes ``.jpg`` (same bytes) and other formats are re-encoded as ``.png``."""
    ext = Path(name).suffix
    if ext in (".jpg", ".JPG", ".png"):
        return ext
    return ".jpg" if ext.lower() in _JPEG else ".png"


def synthetic_ext(real_names: Sequence[str]) -> str:
    """Synthesized views in the photos' family: JPEG (quality 95) when the first photo is JPEG, else PNG
    (gsplat and NeRF look at the first file's extension)."""
    return ".jpg" if real_names and Path(real_names[0]).suffix.lower() in _JPEG else ".png"


def layout(scene: Scene, info: DenseInfo) -> tuple[Scene, DenseSplit, list[str]]:
    """The dense scene as written: frames in :func:`safe_order`, renamed with rank prefixes; its split;
    and each written frame's original name. Observations follow the renaming."""
    frames = sorted(scene.frames, key=lambda f: f.index)
    flags = [f.synthetic for f in frames]
    order = safe_order(flags)
    safe = order is not None
    if order is None:
        log.warning(
            "%d real and %d synthesized views: too few real photos to fill every %dth position, so "
            "gsplat/NeRF/3DGS position-based test sets would include synthesized views; use their "
            "split options (see the README, 'Use the dense scene with ...')",
            flags.count(False),
            flags.count(True),
            EVERY,
        )
        order = list(range(len(frames)))
    frames = [frames[i] for i in order]
    real_names = [f.name for f in frames if not f.synthetic]
    syn = synthetic_ext(real_names)
    names = rank_names([f.name for f in frames], [syn if f.synthetic else llff_ext(f.name) for f in frames])
    held = set(info.holdout)
    unknown = held - set(real_names)
    if unknown:
        raise ValueError(f"holdout names not among the real frames: {sorted(unknown)}")
    positional = positional_test(frames) if safe else None
    if not info.test_split:
        held, rule = set(), "none: every photo fed training and synthesis"
    elif held:
        rule = "the real photos held out of training and synthesis"
        if held == set(positional or ()):
            rule += f": every {EVERY}th image of all in name order, the images position-based loaders test"
    elif positional is not None:  # held out of nothing (a run trained on every photo): still the loaders' set
        held, rule = set(positional), f"every {EVERY}th image of all in name order (what position-based loaders test)"
    else:
        real_by_index = sorted((f for f in frames if not f.synthetic), key=lambda f: f.index)
        held = {f.name for f in real_by_index[::EVERY]}
        rule = f"every {EVERY}th real photo in capture order, from the first"
    test = [n for f, n in zip(frames, names) if f.name in held]
    train = tuple(n for f, n in zip(frames, names) if f.name not in held)
    split = DenseSplit(train=train, val=tuple(test), test=tuple(test), rule=rule, positional_safe=safe)
    renamed = [replace(f, name=n) for f, n in zip(frames, names)]
    obs = {n: scene.observations[f.name] for f, n in zip(frames, names) if f.name in scene.observations}
    return replace(scene, frames=renamed, observations=obs), split, [f.name for f in frames]


def write_split_files(folder: Path, split: DenseSplit) -> None:
    """nerfstudio's COLMAP parser lists (``train_list.txt``, ``val_list.txt``, ``test_list.txt`` in the
    scene folder) and 3DGS' ``sparse/0/test.txt``; none without a test split."""
    if not split.test:
        return
    for key, fname in LIST_FILES.items():
        (Path(folder) / fname).write_text("".join(n + "\n" for n in getattr(split, key)))
    model = Path(folder) / "sparse" / "0"
    if model.is_dir():
        (model / "test.txt").write_text("".join(n + "\n" for n in split.test))


def write_sparself_json(folder: Path, scene: Scene, split: DenseSplit, sources: Sequence[str], info: DenseInfo) -> Path:
    """``sparself.json``: format version, run and plan, each frame's flag/index/original name, the split."""
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "run": info.run,
        "plan": info.plan,
        "test_every": EVERY,
        "position_based_test_sets_are_real": split.positional_safe,
        "split": {"rule": split.rule, "train": list(split.train), "val": list(split.val), "test": list(split.test)},
        "frames": [_frame_doc(f, s, info.made_from) for f, s in zip(scene.frames, sources)],
    }
    if info.selfcheck is not None:
        doc[SelfCheck.KEY] = info.selfcheck.to_json()
    out = Path(folder) / SPARSELF_JSON
    out.write_text(json.dumps(doc, indent=1) + "\n")
    return out


def _frame_doc(frame, source_name: str, made_from: dict[str, MadeFrom]) -> dict:
    """A frame's entry in sparself.json; a synthesized one names the photos it was made from."""
    doc = {
        "name": frame.name,
        "synthetic": bool(frame.synthetic),
        "index": float(frame.index),
        "source_name": source_name,
    }
    if frame.synthetic and source_name in made_from:
        doc["made_from"] = {
            "warped": list(made_from[source_name].warped),
            "sequence": list(made_from[source_name].sequence),
        }
    return doc


def read_synthetic_names(folder: Path) -> set[str] | None:
    """Names of the synthesized frames listed in ``folder/sparself.json``; None when there is none."""
    p = Path(folder) / SPARSELF_JSON
    if not p.is_file():
        return None
    try:
        doc = json.loads(p.read_text())
        return {str(fr["name"]) for fr in doc["frames"] if fr.get("synthetic")}
    except (OSError, ValueError, KeyError, TypeError):
        log.warning("%s: unreadable; synthesized frames are not marked", p)
        return None


def read_selfcheck(folder: Path) -> SelfCheck | None:
    """The self-check recorded in ``folder/sparself.json``; None when there is none (InputError naming the file
    when it is unreadable)."""
    p = Path(folder) / SPARSELF_JSON
    try:
        doc = json.loads(p.read_text()) if p.is_file() else {}
        return SelfCheck.from_json(doc[SelfCheck.KEY]) if SelfCheck.KEY in doc else None
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"{p}: unreadable self-check record ({e})") from None


def downscaled_size(width: int, height: int, factor: int) -> tuple[int, int]:
    """Size of an ``images_<factor>`` copy: floor division, as nerfstudio (default rounding) and gsplat
    (``cam.width // factor``) compute the camera; at least 1 px."""
    return max(1, width // factor), max(1, height // factor)


def write_downscaled(folder: Path, scene: Scene, factors: Sequence[int] = FACTORS) -> None:
    """``images_<f>/<name>`` for every frame (real and synthesized alike), from the written ``images/``."""
    for i, f in enumerate(scene.frames):
        img = load_image(Path(folder) / "images" / f.name, warn=False) if f.image is None else f.image
        w, h = scene.image_size(i)
        for k in factors:
            dst = Path(folder) / f"images_{k}" / f.name
            dst.parent.mkdir(parents=True, exist_ok=True)
            save_image(dst, resize_image(np.asarray(img, np.float32), downscaled_size(w, h, k)))


def mark_synthetic(scene: Scene, names: set[str]) -> Scene:
    """Frames whose name is in ``names`` get ``synthetic=True``."""
    scene.frames = [replace(f, synthetic=True) if f.name in names else f for f in scene.frames]
    return scene


def mask_name(image_name: str) -> str:
    """The mask file of an image: same stem, always ``.png`` (lossless, single channel)."""
    return str(Path(image_name).with_suffix(".png"))


def mask_values(confidence: np.ndarray) -> np.ndarray:
    """8-bit mask of a confidence map (H, W) in [0, 1]: round(255 c), and 0 below :data:`MASK_FLOOR`
    (nerfstudio ignores 0 and uses every other value; a reader that weights pixels gets c)."""
    c = np.clip(np.nan_to_num(np.asarray(confidence, np.float32)), 0.0, 1.0)
    m = np.maximum(np.round(c * 255.0), 1).astype(np.uint8)
    m[c < MASK_FLOOR] = 0
    return m


def write_masks(folder: Path, scene: Scene, factors: Sequence[int] = ()) -> None:
    """``masks/<stem>.png`` for every frame: a synthesized frame's confidence (:func:`mask_values`), 255
    for a real photo (nerfstudio needs a mask for every frame or none); and ``masks_<f>`` copies at the
    ``images_<f>`` sizes (nearest neighbour, so that ignored pixels stay 0)."""
    for i, f in enumerate(scene.frames):
        w, h = scene.image_size(i)
        conf = scene.confidence_map(i)  # in memory, or the mask a scene read back came with
        conf = np.ones((h, w), np.float32) if conf is None else conf
        mask = Image.fromarray(mask_values(conf), mode="L")
        if mask.size != (w, h):
            mask = mask.resize((w, h), Image.Resampling.NEAREST)
        for k, sub in [(1, MASKS)] + [(k, f"{MASKS}_{k}") for k in factors]:
            dst = Path(folder) / sub / mask_name(f.name)
            dst.parent.mkdir(parents=True, exist_ok=True)
            (mask if k == 1 else mask.resize(downscaled_size(w, h, k), Image.Resampling.NEAREST)).save(dst)


# ---- reading masks back -----------------------------------------------------------------------------
# A mask value m is read as confidence m / 255: round(255 c) / 255 for what sparself wrote, within 1/255 of c,
# and 0 where c was below MASK_FLOOR. An all-255 mask (a real photo) is the same as no map.


def checked_mask(path: Path, size: tuple[int, int], listed: str = "") -> Path | None:
    """``path`` when it is a readable 8-bit mask of the image's size (W, H) that holds a value below 255;
    None when every pixel is 255 (no map: the plain loss). InputError naming the file otherwise (``listed``
    says where it was named). Decoded once here to check it; kept as a path, read again when used."""
    where = f" ({listed})" if listed else ""
    try:
        m = read_mask(path)
    except InputError as e:
        raise InputError(f"{e}{where}") from None
    if (m.shape[1], m.shape[0]) != tuple(size):
        raise InputError(f"{path}: mask is {m.shape[1]}x{m.shape[0]} but its image is {size[0]}x{size[1]}{where}")
    return None if m.min() == 255 else Path(path)


def masks_folder(image_dir: Path) -> Path | None:
    """The mask folder :func:`write_masks` lays beside an image folder: ``images`` -> ``masks``,
    ``images_4`` -> ``masks_4``; None for a folder of another name."""
    name = Path(image_dir).name
    return Path(image_dir).parent / (MASKS + name[len("images") :]) if name.startswith("images") else None


def read_masks_beside(scene: Scene, image_dir: Path) -> Scene:
    """COLMAP / LLFF: each frame's ``mask`` from ``<stem>.png`` in :func:`masks_folder` (:func:`checked_mask`),
    when that folder holds one for every frame (as sparself writes them; nerfstudio takes all or none)."""
    folder = masks_folder(image_dir)
    if folder is None or not folder.is_dir():
        return scene
    files = [folder / mask_name(f.name) for f in scene.frames]
    found = sum(p.is_file() for p in files)
    if found < len(files):
        if found:
            log.warning(
                "%s: masks for %d of %d images; masks are read only when every image has one", folder, found, len(files)
            )
        return scene
    for i, (f, p) in enumerate(zip(scene.frames, files)):
        f.mask = checked_mask(p, scene.image_size(i))
    return scene
