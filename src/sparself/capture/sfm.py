"""Camera poses and intrinsics from photos with pycolmap (SIFT, exhaustive/sequential matching, incremental
mapping), tuned for SPARSE captures (about 25 views around an object), plus a pose comparison up to a
similarity transform.

Why not pycolmap's defaults: on 25 evenly spaced views of ``llff_bird`` (every 7th of a 360-degree orbit),
neighbouring views are ~14 degrees apart and share few SIFT matches; the defaults (8192 features, no
guided matching, 100 inliers to initialise, 30 to register) leave most views unregistered. The values in
:class:`SfmConfig` were chosen by measurement on that capture and on the Middlebury sparse rings (see the
field comments).
"""

from __future__ import annotations

import logging
import shutil
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator, Literal, Sequence

import numpy as np

from sparself.capture.images import image_size_of, list_images
from sparself.capture.io.colmap import scene_from_reconstruction
from sparself.capture.photos import exif_focal_px, validate_images
from sparself.capture.posecheck import ImageStats, PoseCheck, Suspect, camera_warnings, check_poses
from sparself.capture.scene import Scene, undistorted
from sparself.capture.sfm_images import WorkImages, work_images
from sparself.core.errors import InputError, RegistrationError
from sparself.core.interrupts import import_native
from sparself.core.names import capture_key
from sparself.core.outputs import scratch_dir
from sparself.core.space import MB, check_free_space, files_size

log = logging.getLogger(__name__)


@dataclass
class SfmConfig:
    """Options of :func:`recover_poses`.

    matcher: "exhaustive" (all pairs; best for ~25 unordered or orbit views) or "sequential" (each image
             with its ``sequential_overlap`` successors in capture order, IMG_2 before IMG_10; for long
             video-like captures).
    max_image_size: longest side (px) the images are downscaled to for feature extraction; 0 = full size.
             Cameras and keypoints are still expressed at full resolution.
    single_camera: one shared camera for all images (a single phone/lens) or one per image.
    camera_model: COLMAP model of the recovered camera(s).
    """

    matcher: Literal["exhaustive", "sequential"] = "exhaustive"
    max_image_size: int = 1600  # phone photos (4000 px) extract ~6x faster; bird keeps 25/25 even at 480
    single_camera: bool = True
    camera_model: str = "SIMPLE_RADIAL"
    seed: int = 0
    num_threads: int = -1  # threads per stage (-1 = all cores), used when not deterministic
    deterministic: bool = True  # one thread everywhere: same seed -> same poses. Multi-threaded
    # matching/bundle adjustment reorder work and results drift (measured)
    sequential_overlap: int = 10
    # --- feature extraction -----------------------------------------------------------------------
    max_num_features: int = 16384  # default 8192: more features -> more matches between far views
    peak_threshold: float = 0.004  # default 0.0067: lower -> features on weakly textured objects
    domain_size_pooling: bool = False  # DSP-SIFT descriptors (default off)
    estimate_affine_shape: bool = False  # affine-covariant SIFT (default off)
    # --- matching ---------------------------------------------------------------------------------
    guided_matching: bool = True  # default False: re-matches with the epipolar geometry
    min_num_inliers: int = 15  # two-view verification (default 15)
    # --- incremental mapping ----------------------------------------------------------------------
    min_num_matches: int = 15  # pairs with fewer verified matches are ignored (default 15)
    init_min_num_inliers: int = 50  # default 100: the initial pair of a sparse capture has fewer
    init_min_tri_angle: float = 8.0  # default 16 degrees
    abs_pose_min_num_inliers: int = 15  # default 30: register views that see fewer triangulated points
    abs_pose_min_inlier_ratio: float = 0.15  # default 0.25
    min_model_size: int = 3  # default 10: a sparse capture may have fewer than 10 views
    max_reg_trials: int = 5  # default 3
    debug: bool = False  # pycolmap's own (glog) logging to stderr


@dataclass
class SfmReport:
    """What :func:`recover_poses` did: counts, names of images not registered, timings per stage."""

    num_images: int
    registered: list[str]
    unregistered: list[str]
    num_models: int
    num_points: int
    mean_reprojection_error: float
    timings: dict[str, float] = field(default_factory=dict)
    suspects: list[Suspect] = field(default_factory=list)  # registered, but the pose is probably wrong
    pose_check: str = ""  # why the jump check was skipped, if it was; how neighbours were taken
    breaks: list[str] = field(default_factory=list)  # jumps between two large parts that each agree
    repair: str = ""  # what was tried on suspects, and how it ended
    camera: list[str] = field(default_factory=list)  # implausible-camera warnings

    @property
    def num_registered(self) -> int:
        return len(self.registered)

    def summary(self) -> str:
        s = f"registered {self.num_registered} of {self.num_images} images"
        if self.unregistered:
            s += f"; not registered: {', '.join(self.unregistered)}"
        if self.suspects or self.breaks:
            s += "; " + PoseCheck(self.suspects, breaks=self.breaks).summary()
        elif self.repair:
            s += "; suspect poses repaired"
        if self.repair:
            s += f" [{self.repair}]"
        return s


# ---- pycolmap --------------------------------------------------------------------------------------


@contextmanager
def _quiet_colmap(debug: bool) -> Iterator[None]:
    pycolmap = import_native("pycolmap")

    old = pycolmap.logging.minloglevel
    # 3 = FATAL only: its ERROR lines ("Failed to create any sparse model") would precede our own one-line
    # error (RegistrationError) as noise; --debug shows everything
    pycolmap.logging.minloglevel = 0 if debug else 3
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def _options(cfg: SfmConfig):
    pycolmap = import_native("pycolmap")

    ext = pycolmap.FeatureExtractionOptions()
    ext.max_image_size = cfg.max_image_size if cfg.max_image_size > 0 else -1
    ext.num_threads = cfg.num_threads
    ext.sift.max_num_features = cfg.max_num_features
    ext.sift.peak_threshold = cfg.peak_threshold
    ext.sift.domain_size_pooling = cfg.domain_size_pooling
    ext.sift.estimate_affine_shape = cfg.estimate_affine_shape

    match = pycolmap.FeatureMatchingOptions()
    match.num_threads = cfg.num_threads
    match.guided_matching = cfg.guided_matching

    verify = pycolmap.TwoViewGeometryOptions()
    verify.min_num_inliers = cfg.min_num_inliers
    verify.ransac.random_seed = cfg.seed

    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.num_threads = cfg.num_threads
    mapper.random_seed = cfg.seed
    mapper.min_num_matches = cfg.min_num_matches
    mapper.min_model_size = cfg.min_model_size
    mapper.extract_colors = True
    m = mapper.mapper
    m.init_min_num_inliers = cfg.init_min_num_inliers
    m.init_min_tri_angle = cfg.init_min_tri_angle
    m.abs_pose_min_num_inliers = cfg.abs_pose_min_num_inliers
    m.abs_pose_min_inlier_ratio = cfg.abs_pose_min_inlier_ratio
    m.max_reg_trials = cfg.max_reg_trials
    m.random_seed = cfg.seed
    m.num_threads = mapper.num_threads
    mapper.triangulation.random_seed = cfg.seed
    return ext, match, verify, mapper


def _colmap_run(paths: Sequence[Path], work: Path, cfg: SfmConfig, timings: dict[str, float]):
    """Features, matching and incremental mapping in ``work``, on the photos under aliases in capture order
    (:mod:`sparself.capture.sfm_images`). -> (reconstructions with the user's names, database, the photos)."""
    pycolmap = import_native("pycolmap")

    ext, match, verify, _ = _options(cfg)
    pycolmap.set_random_seed(cfg.seed)
    db = work / "database.db"
    images = work_images(paths, work)
    t0 = time.perf_counter()
    longest = max(max(image_size_of(p)) for p in paths)
    log.info(
        "sfm: extracting SIFT features from %d images%s",
        len(paths),
        f" (downscaled from {longest} to {cfg.max_image_size} px)" if 0 < cfg.max_image_size < longest else "",
    )
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cfg.camera_model
    pycolmap.extract_features(
        db,
        images.folder,
        image_names=list(images.aliases),
        camera_mode=pycolmap.CameraMode.SINGLE if cfg.single_camera else pycolmap.CameraMode.PER_IMAGE,
        reader_options=reader,
        extraction_options=ext,
        device=pycolmap.Device.cpu,
    )
    timings["features"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    log.info("sfm: %s matching", cfg.matcher)
    if cfg.matcher == "exhaustive":
        pycolmap.match_exhaustive(db, matching_options=match, verification_options=verify, device=pycolmap.Device.cpu)
    else:  # pairs each image with its successors in name order: the aliases' order, capture order
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = cfg.sequential_overlap
        pycolmap.match_sequential(
            db, matching_options=match, pairing_options=pairing, verification_options=verify, device=pycolmap.Device.cpu
        )
    timings["matching"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    log.info("sfm: incremental mapping")
    recs = _mapping(db, images, work / "sparse", cfg, reseed=False)
    timings["mapping"] = time.perf_counter() - t0
    return recs, db, images


def _mapping(db: Path, images: WorkImages, out: Path, cfg: SfmConfig, reseed: bool = True) -> dict:
    """Incremental mapping; its reconstructions name the photos as the user does."""
    pycolmap = import_native("pycolmap")

    out.mkdir()
    if reseed:  # a repair run starts from the same random state as the first mapping would from scratch
        pycolmap.set_random_seed(cfg.seed)
    recs = pycolmap.incremental_mapping(db, images.folder, out, _options(cfg)[3])
    return {k: images.to_user_names(r) for k, r in recs.items()}


def _best(recs: dict):
    return max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D())) if recs else None


def recover_poses(
    image_folder: Path,
    cfg: SfmConfig | None = None,
    *,
    names: Sequence[str] | None = None,
    beside: Path | None = None,
) -> tuple[Scene, SfmReport]:
    """Recover intrinsics and poses of the photos in ``image_folder`` (all images, or ``names``), check them
    (:mod:`sparself.capture.posecheck`: pose jumps between capture-order neighbours, weak photos, an implausible
    camera) and try to repair suspect poses (:func:`_repair`).

    Runs in a temporary folder (removed afterwards): beside the output ``beside``, named as its temporary
    folders, else in the system temp; the input folder is only read.
    -> (scene of the registered images: frames sorted by name, paths into ``image_folder``, sparse points;
        report). Raises InputError for bad photos, RegistrationError if fewer than 3 are registered.
    """
    cfg = cfg or SfmConfig()
    if cfg.matcher not in ("exhaustive", "sequential"):
        raise InputError(f"unknown matcher {cfg.matcher!r} (use 'exhaustive' or 'sequential')")
    folder = Path(image_folder)
    paths = validate_images(folder, names)
    names = [p.name for p in paths]
    if cfg.matcher == "exhaustive" and len(names) > 150:
        log.warning(
            "sfm: %d images with exhaustive matching compares %d pairs; --matcher sequential is "
            "much faster for long ordered captures",
            len(names),
            len(names) * (len(names) - 1) // 2,
        )
    if cfg.deterministic:
        cfg = replace(cfg, num_threads=1)
    timings: dict[str, float] = {}
    with scratch_dir(beside, "sfm") as work, _quiet_colmap(cfg.debug):
        recs, db, images = _colmap_run(paths, work, cfg, timings)
        best = _best(recs)
        if best is None:
            raise RegistrationError(
                f"{folder}: COLMAP could not register any of the {len(names)} images "
                "(too little overlap or texture between the photos)"
            )
        t0 = time.perf_counter()
        check = check_poses(_posed(best), image_stats(best))
        repair = ""
        if check.suspects:
            best, check, repair = _repair(best, check, db, images, work, cfg, names)
        timings["check"] = time.perf_counter() - t0
    scene = undistorted(scene_from_reconstruction(best, folder, source=folder))
    return scene, _report(scene, names, recs, best, check, repair, timings, paths)


def _posed(rec) -> Scene:
    return scene_from_reconstruction(rec, None)


def _report(
    scene: Scene,
    names: list[str],
    recs: dict,
    best,
    check: PoseCheck,
    repair: str,
    timings: dict[str, float],
    paths: Sequence[Path],
) -> SfmReport:
    """The report, its log lines (warnings, so that -q and densify show them), the final checks."""
    folder = paths[0].parent
    registered = [f.name for f in scene.frames]
    unregistered = [n for n in names if n not in set(registered)]
    recovered = [lens.lens for lens in scene.undistort.values()] + [
        cam for cid, cam in scene.cameras.items() if cid not in scene.undistort
    ]
    cam_notes = [w for cam in recovered for w in camera_warnings(cam, exif_focal_px(paths, cam.width, cam.height))]
    report = SfmReport(
        num_images=len(names),
        registered=registered,
        unregistered=unregistered,
        num_models=len(recs),
        num_points=best.num_points3D(),
        mean_reprojection_error=float(best.compute_mean_reprojection_error()),
        timings=timings,
        suspects=check.suspects,
        pose_check="; ".join(x for x in (check.skipped, check.order) if x),
        breaks=check.breaks,
        repair=repair,
        camera=cam_notes,
    )
    scene.source_format, scene.unregistered = "sfm", tuple(unregistered)
    log.log(
        logging.WARNING if unregistered or check.suspects or check.breaks else logging.INFO,
        "sfm: %s (%s; %.1f s)",
        report.summary(),
        "one model" if len(recs) == 1 else f"the largest of {len(recs)} models",
        sum(timings.values()),
    )
    for w in cam_notes:
        log.warning("sfm: %s", w)
    if len(registered) < 3:
        raise RegistrationError(
            f"{folder}: only {len(registered)} of {len(names)} images could be registered "
            f"({', '.join(registered) or 'none'}); need at least 3. Not registered: "
            f"{', '.join(unregistered)}"
        )
    return report


def image_stats(rec) -> list[ImageStats]:
    """Per registered image of a pycolmap reconstruction: 3D points seen, their mean track length, and the
    mean reprojection error of its own observations (px)."""
    out = []
    for img in sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: capture_key(im.name)):
        obs = img.get_observation_points2D()
        if not len(obs):
            out.append(ImageStats(img.name, 0, 0.0, float("inf")))
            continue
        pts = [rec.points3D[p.point3D_id] for p in obs]
        X = np.array([p.xyz for p in pts])
        xy = np.array([p.xy for p in obs])
        cam_pts = X @ np.asarray(img.cam_from_world().rotation.matrix()).T + np.asarray(
            img.cam_from_world().translation
        )
        proj = np.asarray(img.camera.img_from_cam(cam_pts, check_cheirality=False))
        err = np.linalg.norm(proj - xy, axis=1)
        out.append(ImageStats(img.name, len(pts), float(np.mean([p.track.length() for p in pts])), float(np.mean(err))))
    return out


def _restricted_db(db: Path, dst: Path, keep, user: dict[str, str]) -> int:
    """A copy of the database without the verified pairs that ``keep(a, b)`` (the user's image names; ``user``
    maps the database's aliases to them) refuses. -> number of pairs removed."""
    pycolmap = import_native("pycolmap")

    shutil.copyfile(db, dst)
    d = pycolmap.Database.open(dst)
    try:
        names = {im.image_id: user[im.name] for im in d.read_all_images()}
        removed = 0
        for pid in d.read_two_view_geometries()[0]:
            a, b = pycolmap.pair_id_to_image_pair(pid)
            if not keep(names[a], names[b]):
                d.delete_two_view_geometry(a, b)
                d.delete_matches(a, b)
                removed += 1
    finally:
        d.close()
    return removed


REPAIR_WINDOW = 3  # capture-order neighbours (either side) a photo keeps its matches with in a repair


def _repair(best, check: PoseCheck, db: Path, images: WorkImages, work: Path, cfg: SfmConfig, names: list[str]):
    """Try to re-register suspect photos: (1) the suspects' matches restricted to their capture-order
    neighbours (wrong matches to far photos of a symmetric object or repetitive floor pull them to mirrored
    poses), (2) every photo's matches restricted so (a sequential order prior). Each is a new incremental
    mapping on a copy of the database, checked again; a result is taken only if it registers as many photos
    and leaves fewer suspects. -> (reconstruction, check, what was tried and how it ended)."""
    pos = {n: i for i, n in enumerate(names)}
    sus = set(check.names)
    near = lambda a, b: abs(pos[a] - pos[b]) <= REPAIR_WINDOW  # noqa: E731
    tries = [
        (
            "matches of the suspects restricted to their capture-order neighbours",
            lambda a, b: (a not in sus and b not in sus) or near(a, b),
        ),
        ("all matches restricted to capture-order neighbours (a sequential order prior)", near),
    ]
    before, done = check.names, []
    for k, (what, keep) in enumerate(tries):
        removed = _restricted_db(db, work / f"repair{k}.db", keep, images.user)
        cand = _best(_mapping(work / f"repair{k}.db", images, work / f"repair{k}", cfg))
        c = check_poses(_posed(cand), image_stats(cand)) if cand is not None else None
        done.append(
            f"{what} ({removed} pairs dropped): "
            + ("no model" if c is None else f"{cand.num_reg_images()} registered, {len(c.suspects)} suspect(s)")
        )
        if c is not None and cand.num_reg_images() >= best.num_reg_images() and len(c.suspects) < len(check.suspects):
            best, check = cand, c
        if not check.suspects:
            break
    return best, check, repair_outcome(before, check.names, done)


def repair_outcome(before: list[str], after: list[str], tried: list[str]) -> str:
    """One plain sentence: what was tried on the suspects and whether it worked."""
    if after:
        end = (
            f"could not repair: {', '.join(after)} still look wrong; check or remove these photos (or add "
            "photos between them and their neighbours) and run again"
        )
    else:
        end = f"repaired: {', '.join(before)} now agree with their neighbours"
    return "tried " + "; ".join(tried) + f". {end}"


# ---- comparison with reference poses ------------------------------------------------------------


# ---- photos -> scene folder ----------------------------------------------------------------------


def poses_to_folder(
    image_folder: Path, out: Path, cfg: SfmConfig | None = None, *, overwrite: bool = False, images: str = "copy"
) -> SfmReport:
    """Recover poses of the photos in ``image_folder`` and write ``out`` atomically in the layout of
    :func:`sparself.capture.io.write_scene` (``images/``, ``sparse/0/``, ``poses_bounds.npy``, ``transforms.json``)
    plus ``sfm_report.json`` (registered / unregistered names, timings, the options used).

    Only registered images are written to ``out/images``; images="copy" copies the original bytes,
    "link" symlinks them. The output folder is checked before COLMAP runs, so a bad ``out`` fails fast.
    """
    import json
    from dataclasses import asdict

    from sparself.capture.io import write_scene_into
    from sparself.core.outputs import Input, atomic_dir, check_output_dir

    cfg = cfg or SfmConfig()
    inputs = [Input("photo folder", image_folder)]
    check_output_dir(Path(out), overwrite, inputs)
    # the photos copied (not linked), and SfM's database beside the output while it runs
    check_free_space(out, (files_size(list_images(image_folder)) if images == "copy" else 0) + 64 * MB)
    scene, report = recover_poses(image_folder, cfg, beside=Path(out))
    with atomic_dir(Path(out), overwrite, inputs) as tmp:
        write_scene_into(scene, tmp, images=images)
        (tmp / "sfm_report.json").write_text(
            json.dumps({"input": str(Path(image_folder).resolve()), **asdict(report), "options": asdict(cfg)}, indent=2)
        )
    return report
