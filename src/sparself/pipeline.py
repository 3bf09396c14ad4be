"""The whole job in one call: photos (or a posed scene) -> poses -> plan -> train -> synthesize -> the
dense scene written for COLMAP, LLFF and nerfstudio (``sparself densify``)."""

from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path

from sparself.capture import io as sio
from sparself.capture.io.dense import MadeFrom, positional_test
from sparself.capture.plot import plot_cameras
from sparself.capture.scene import Scene, preloaded
from sparself.capture.sfm import SfmConfig, recover_poses
from sparself.capture.triangulate import ensure_points
from sparself.core.content import digest, keep, kept
from sparself.core.errors import InputError
from sparself.core.locks import output_lock
from sparself.core.options import option
from sparself.core.outputs import Input, atomic_dir, check_output_dir, real, scene_inputs, work_dir
from sparself.core.space import MB, check_free_space, files_size
from sparself.evaluation.selfcheck import Checked, SelfCheckConfig, checked_views
from sparself.synthesis.plan import PlanConfig, plan_sequence, save_plan
from sparself.synthesis.run import Run
from sparself.synthesis.synthesize import Synthesized, densify_scene, synthesize_with_confidence
from sparself.synthesis.train import MIN_TRAIN, check_holdout, train, train_resumable
from sparself.synthesis.train_config import TrainConfig

log = logging.getLogger(__name__)

POSES = "poses.pkl"  # in the work folder: what SfM recovered


@dataclass
class DensifyConfig:
    """Options of the whole pipeline. out_size: long side in px of the written scene (None = as read);
    training runs at that size too (``train.size`` is replaced by it). check: the reconstruction the views are
    planned for and checked against (``check.recon="none"``: the paper's plan, every view written)."""

    train: TrainConfig = field(default_factory=TrainConfig)
    plan: PlanConfig = field(default_factory=PlanConfig)
    check: SelfCheckConfig = field(default_factory=SelfCheckConfig)
    sfm: SfmConfig = field(default_factory=SfmConfig)
    out_size: int | None = None
    overwrite: bool = False
    keep_run: bool = True
    downscaled: bool = option(True, "write images_2/4/8 copies beside images/ (worth turning off for large scenes)")
    triangulate: bool = option(
        True,
        "triangulate sparse points for a capture that has none, from its real photos at their known poses",
    )
    test_split: bool = option(
        True,
        "write a test split: the photos position-based loaders test (every 8th of all images) feed neither "
        "training nor synthesis (off: every photo feeds both and no test split is written)",
    )


def read_input(path: Path, cfg: DensifyConfig, out: Path | None = None, work: Path | None = None) -> Scene:
    """A scene from anything read_scene accepts, else a folder of photos posed with SfM (its scratch
    folder beside ``out``; the poses kept in ``work``, when given, and read back from there while the photos and
    the SfM options are the same)."""
    try:
        sio.detect_format(path)
    except InputError:
        pass  # no pose file here: a folder of photos (list_images/recover_poses say what is wrong with it)
    else:
        return sio.read_scene(path)  # a broken pose file is reported, not silently replaced by SfM
    key = digest((real(path), sorted(path.iterdir()) if path.is_dir() else [], cfg.sfm))
    saved = kept(work / POSES) if work is not None else None
    if isinstance(saved, _Posed) and saved.key == key:
        log.info("%s: the poses a stopped run recovered (%d photos)", path, len(saved.scene))
        return saved.scene
    log.info("%s: no poses found; recovering them with structure from motion", path)
    scene, _ = recover_poses(path, cfg.sfm, beside=out)  # it logs what was registered and what not
    if work is not None:
        keep(work / POSES, _Posed(key, scene))
    return scene


@dataclass(frozen=True)
class _Posed:
    """The poses SfM recovered, kept for a resumed run with the digest of the photos and options they came from."""

    key: str
    scene: Scene


def densify(photos_or_scene, out: Path | str, cfg: DensifyConfig | None = None, resume: bool = False) -> Scene:
    """Photos (or a posed scene) -> poses -> plan -> train -> synthesize -> written dense scene.

    photos_or_scene: a Scene, or a path read by ``sparself.capture.io.read_scene`` or a folder of photos (SfM).
    out: folder written atomically: the dense scene in ``out/scene/`` (``sparself.capture.io.write_scene`` layout:
    images/, sparse/0/, poses_bounds.npy, transforms.json), the plan in ``out/plan.json``, a camera plot
    ``out/cameras.png`` and, if ``keep_run``, the trained run in ``out/run/``. Returns the densified scene.
    While it runs, the finished steps (SfM's poses, the network's checkpoints, the self-check's fits) are kept in
    a work folder beside ``out`` (:func:`~sparself.core.outputs.work_path`), left there when the run is stopped;
    ``resume`` continues from them, to the same result as a run never stopped.
    """
    cfg = cfg or DensifyConfig()
    cfg.check.validate()
    out = Path(out)
    given = isinstance(photos_or_scene, Scene)
    check_output_dir(out, cfg.overwrite, scene_inputs(photos_or_scene) if given else [Input("input", photos_or_scene)])
    with output_lock(out), work_dir(out, resume) as work:
        scene = photos_or_scene if given else read_input(Path(photos_or_scene), cfg, out, work)
        return _densify(scene, out, cfg, work)


def _densify(scene: Scene, out: Path, cfg: DensifyConfig, work: Path | None) -> Scene:
    """:func:`densify` from the posed scene on, the network trained in ``work`` (the fits are kept there too:
    :meth:`~sparself.recon.pool.Fitter.many`)."""
    check_output_dir(out, cfg.overwrite, scene_inputs(scene))  # before any training
    photos = scene  # at their own size: triangulation matches them at up to 800 px
    if cfg.out_size:
        scene = preloaded(scene.resized(cfg.out_size))
    scene, targets = plan_sequence(scene, cfg.plan)  # sources on the plan's index scale
    # train at the output resolution: the sweep decoder's windows are in pixels, and training cost depends
    # on the crop size, not on the image size
    long_side = max(max(c.width, c.height) for c in scene.cameras.values())
    tcfg = replace(cfg.train, size=long_side)
    if cfg.test_split and not tcfg.holdout:
        tcfg = replace(tcfg, holdout=test_positions(scene, targets))
    check_holdout(tcfg.holdout, scene)
    check_free_space(out, densify_bytes(photos, len(targets), cfg.downscaled))
    holdout = tuple(scene.frames[i].name for i in tcfg.holdout)
    with atomic_dir(out, cfg.overwrite) as tmp:
        run = train(scene, tmp / "run", tcfg) if work is None else train_resumable(work / "runs", scene, tcfg)
        # points for the written scene (training and synthesis are the same with or without them) and the fits
        written = _with_points(scene, photos, holdout) if cfg.triangulate else scene
        planned, views, made_from = _views(run, scene, written, targets, cfg, tcfg.holdout)
        dense = densify_scene(written, views.frames, views.images, views.confidence)
        info = sio.DenseInfo(
            "../run" if cfg.keep_run else None,
            "../plan.json",
            holdout,
            cfg.downscaled,
            cfg.test_split,
            {f.name: made_from[f.name] for f in views.frames if f.name in made_from},
            views.record,
        )
        sio.write_scene_into(dense, tmp / "scene", dense=info)
        # the plan and a camera plot beside the scene, so users see where the new views are
        save_plan(tmp / "plan.json", planned, scene=scene, cfg=cfg.plan)
        plot_cameras(
            scene,
            planned=views.frames,
            path=tmp / "cameras.png",
            title=f"{len(scene)} input views (blue) + {len(views.frames)} synthesized (orange)",
        )
        assert run.path is not None
        if cfg.keep_run and run.path != tmp / "run":
            shutil.move(run.path, tmp / "run")  # a rename beside --out: no second copy of the checkpoint
        elif not cfg.keep_run and run.path == tmp / "run":
            shutil.rmtree(run.path)
    return dense


def test_positions(scene: Scene, targets: list) -> tuple[int, ...]:
    """Positions in ``scene`` of the photos that position-based loaders will test in the written dense scene
    (kept out of training and synthesis); none, with a warning, when too few photos would be left to train."""
    names = positional_test(list(scene.frames) + [replace(t, synthetic=True) for t in targets]) or []
    held = tuple(i for i, f in enumerate(scene.frames) if f.name in names)
    if len(scene) - len(held) < MIN_TRAIN:
        log.warning(
            "%d photos: too few to keep the %d test photos out of training and synthesis; they feed both "
            "(the test split is still written)",
            len(scene),
            len(held),
        )
        return ()
    return held


def densify_bytes(photos: Scene, n_new: int, downscaled: bool) -> int:
    """About what ``densify`` writes: the photos, as many new views per photo as planned (a synthesized view
    weighs about a photo), the images_2/4/8 copies (a third more) and the run's checkpoint."""
    per_view = files_size(f.path for f in photos.frames) / max(len(photos), 1)
    views = (len(photos) + n_new) * per_view * (4 / 3 if downscaled else 1)
    return int(views + 64 * MB)


def _views(
    run: Run, scene: Scene, written: Scene, targets: list, cfg: DensifyConfig, holdout: tuple[int, ...]
) -> tuple[list, Checked, dict[str, MadeFrom]]:
    """(the planned frames, the views to write, the photos that fed each view): all synthesized from the photos
    minus ``holdout`` (positions); every view of the paper's plan with ``check.recon`` none;
    else planned as :func:`~sparself.evaluation.selfcheck.plan_of` says and kept only where they pay
    (:func:`sparself.evaluation.selfcheck.self_check`, on ``written``'s photos minus the user's holdout)."""
    check = cfg.check
    if check.recon == "none":
        if check.plan_mode == "weak":
            log.info("--recon none: the paper's plan (planning where a reconstruction is weak needs one)")
        syn = synthesize_with_confidence(run, scene.without(holdout), targets)
        return targets, Checked(targets, syn.images, syn.confidence, None), syn.sources_by_name(targets)
    synth = lambda sc, tg, **_: synthesize_with_confidence(run, sc, tg)  # noqa: E731
    targets, checked, final = checked_views(
        written.without(holdout), targets, cfg.plan, synth, check, scene.without(holdout)
    )
    assert isinstance(final, Synthesized)  # the run's answer, not a baseline's array
    return targets, checked, final.sources_by_name(targets)


def _with_points(scene: Scene, photos: Scene, holdout: tuple[str, ...]) -> Scene:
    """``scene`` with sparse points triangulated from the real photos of ``photos`` (never a held-out one)
    when it has too few (:func:`sparself.capture.triangulate.ensure_points`)."""
    return ensure_points(scene, photos.subset([i for i, f in enumerate(photos.frames) if f.name not in holdout]))
