"""Is a registered reconstruction right? Checks of recovered cameras that COLMAP's own success does not make.

Pose jumps. A capture is taken in order (file names), so neighbouring photos have neighbouring poses. On a
symmetric object or a repetitive floor, SfM can register a photo (or a run of photos) at a mirrored pose:
150-170 degrees from its neighbours while the capture's median step is 10-30 degrees, and nothing fails.
The rule, in capture order:

* the capture's typical step is the median, over neighbours (i, i+1), of the angle between their viewing
  directions (optical axes) and of the camera-centre distance;
* photos i and j (|i - j| <= WINDOW) agree when their rotation differs by at most ``rot_limit`` and their
  centres by at most ``step_limit + (|i - j| - 1) * median_step``, with
  ``rot_limit = min(max(K * median_rot, ROT_FLOOR_DEG), ROT_CAP_DEG)`` and
  ``step_limit = max(K * median_step, STEP_FLOOR * scale)`` (scale: median distance of the centres to their
  mean). K = 5: five times the typical step is far outside a hand-held capture's unevenness (llff_bird's
  largest step is 1.6x its median, the Middlebury rings' 1.1x), while a flip is 5-20x. The floor keeps
  dense captures (1-2 degrees per step) from flagging ordinary unevenness; the cap (90 degrees: no two
  neighbours of a capture meant for view synthesis look that differently) keeps captures with big steps
  (12 photos around an object) from hiding a flip. Rotation gets no allowance for the photos skipped
  (a photo turned 160 degrees about the vertical looks like a photo five 30-degree steps further on;
  only its neighbours tell);
* photos that agree are linked (WINDOW = 2: neighbours, and the photos either side of one photo); the
  largest linked group is trusted, and every other group of at most a quarter of the photos is suspect.
  A single flipped photo is named exactly (the photos around it agree across it), and so is a flipped
  run that is a small part of the capture; a split into large parts that each agree within themselves
  is reported as a break between two named photos, not as suspects.

Per-image signs (from the SfM model, when given): a mean reprojection error above
``max(ERR_K * median, ERR_FLOOR_PX)``, or a mean track length (how many photos see the image's 3D points)
below ``TRACK_K * median`` and below TRACK_FLOOR: a photo whose points are seen by itself and one other
photo is held by little.

Capture order is file-name order, unless the camera centres walk more than ORDER_RATIO times the length of
a nearest-neighbour path through them (as plan's ``--order auto`` decides, but by centres only, which a
flipped rotation does not change): then neighbours are taken along that path. Except when a few photos
explain it: a photo mirrored across the object lands far from its name neighbours, so a few flips make the
names' path long; when the photos the names' order flags are at most a quarter and the others follow their
names, the names are kept and those photos are the suspects. If even then more than a
quarter of the steps are jumps, the jump check is skipped and the report says so.

Camera plausibility: a horizontal or vertical field of view under 10 or over 150 degrees, or a focal
length more than FOCAL_RATIO times off the one the photos' EXIF gives (35 mm equivalent), is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sparself.capture.scene import Camera, Scene
from sparself.core.geometry import align_similarity, rotation_angle_deg

K = 5.0
ROT_FLOOR_DEG = 30.0
ROT_CAP_DEG = 90.0
STEP_FLOOR = 0.25
WINDOW = 2
ORDER_RATIO = 1.5
ERR_K, ERR_FLOOR_PX = 3.0, 2.0
TRACK_K, TRACK_FLOOR = 0.6, 2.5
# the narrow bound is on the wider side: 6 deg is a ~350 mm lens on a full-frame camera. Middlebury's real rig
# sees 11.0 x 8.2 deg (fx 3310 px at 640x480), and a bound of 10 on the narrower side called it implausible
FOV_MIN_DEG, FOV_MAX_DEG = 6.0, 150.0
FOCAL_RATIO = 1.5


@dataclass
class ImageStats:
    """What the SfM model says about one registered photo."""

    name: str
    num_points: int  # 3D points it observes
    mean_track_length: float  # mean number of photos that see those points
    mean_reprojection_error: float  # px, over its observations


@dataclass
class Suspect:
    """A photo whose pose is probably wrong, and why (readable sentences with the numbers)."""

    name: str
    reasons: list[str]


@dataclass
class PoseCheck:
    """The result of :func:`check_poses`: suspects, and the thresholds the capture gave."""

    suspects: list[Suspect] = field(default_factory=list)
    median_rot_deg: float = 0.0
    median_step: float = 0.0
    rot_limit_deg: float = 0.0
    step_limit: float = 0.0
    skipped: str = ""  # why the jump check did not run (too few photos, no path through the photos)
    order: str = ""  # how neighbours were taken, when not by file name
    breaks: list[str] = field(default_factory=list)  # jumps between two large parts that each agree

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.suspects]

    def summary(self) -> str:
        brk = f"; the capture breaks at {', '.join(self.breaks)}: check the photos there" if self.breaks else ""
        if not self.suspects:
            return "pose check: no suspect photos" + (f" ({self.skipped})" if self.skipped else "") + brk
        return (
            f"{len(self.suspects)} suspect photo(s), poses probably wrong: "
            + "; ".join(f"{s.name} ({', '.join(s.reasons)})" for s in self.suspects)
            + brk
        )


def _rot_between(Rs: np.ndarray, i: int, j: int) -> float:
    """Angle (deg) between the viewing directions of cameras i and j. Not the full relative rotation: a
    photo taken upside down (roll about its optical axis; Middlebury's templeSparseRing has several) is a
    true pose, while a mirrored or flipped registration turns the viewing direction away."""
    return float(np.degrees(np.arccos(np.clip(Rs[i][2] @ Rs[j][2], -1.0, 1.0))))


def _linked_groups(
    Rs: np.ndarray, C: np.ndarray, rot_lim: float, step_lim: float, med_rot: float, med_step: float
) -> list[list[int]]:
    """Groups of photos joined by agreeing pairs within WINDOW of each other in capture order."""
    n = len(Rs)
    parent = list(range(n))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for i in range(n):
        for j in range(i + 1, min(n, i + WINDOW + 1)):
            g = j - i - 1
            if _rot_between(Rs, i, j) <= rot_lim and np.linalg.norm(C[i] - C[j]) <= step_lim + g * med_step:
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    return sorted(groups.values(), key=lambda g: (-len(g), g[0]))


def _jump_reasons(scene: Scene, Rs: np.ndarray, C: np.ndarray, i: int, check: PoseCheck) -> list[str]:
    names = [f.name for f in scene.frames]
    out = []
    for j in (i - 1, i + 1):
        if 0 <= j < len(names):
            r, d = _rot_between(Rs, i, j), float(np.linalg.norm(C[i] - C[j]))
            if r > check.rot_limit_deg:
                out.append(f"looks {r:.0f} deg away from {names[j]}")
            elif d > check.step_limit:
                out.append(f"centre {d / max(check.median_step, 1e-12):.1f}x the median step from {names[j]}")
    if not out:
        out.append("its neighbours agree with each other but not with it")
    return out + [f"median step {check.median_rot_deg:.1f} deg"]


def _centre_path(C: np.ndarray, order: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(C[order], axis=0), axis=1)))


def _neighbour_order(C: np.ndarray) -> np.ndarray:
    """Capture order (0..N-1), or a greedy nearest-neighbour path by camera centre when the file names
    clearly do not follow the capture (see the module doc)."""
    n = len(C)
    capture = np.arange(n)
    best, best_len = capture, np.inf
    for start in dict.fromkeys([0, int(np.argmax(np.linalg.norm(C - C.mean(0), axis=1)))]):
        order, left = [start], set(range(n)) - {start}
        while left:
            rest = np.array(sorted(left))
            nxt = int(rest[np.argmin(np.linalg.norm(C[rest] - C[order[-1]], axis=1))])
            order.append(nxt)
            left.discard(nxt)
        length = _centre_path(C, np.array(order))
        if length < best_len:
            best, best_len = np.array(order), length
    return best if _centre_path(C, capture) > ORDER_RATIO * best_len else capture


def check_poses(scene: Scene, stats: list[ImageStats] | None = None) -> PoseCheck:
    """Suspect photos of a reconstruction whose frames are in capture order (see the module doc)."""
    n = len(scene)
    check = PoseCheck()
    reasons: dict[str, list[str]] = {}
    if n < 4:
        check.skipped = f"{n} photos: too few to compare neighbours"
    else:
        check, reasons = _jumps_in_best_order(scene)
    for name, why in _stat_reasons(stats or []).items():
        reasons.setdefault(name, []).extend(why)
    check.suspects = [Suspect(f.name, reasons[f.name]) for f in scene.frames if f.name in reasons]
    return check


def _jumps_in_best_order(scene: Scene) -> tuple[PoseCheck, dict[str, list[str]]]:
    """The jump check along the file names, unless they do not follow the capture: then along a path by
    camera position. Flipped photos alone can make the names look unordered (each one jumped across the
    object, far from its neighbours, while its mirrored place sits between two other photos, where its
    viewing direction fits); so when the photos the names' order flags are few and the others follow
    their names, the names are the capture order and those photos are the suspects."""
    n = len(scene)
    C = scene.centers()
    order = _neighbour_order(C)
    check = PoseCheck()
    if np.array_equal(order, np.arange(n)):
        return check, _jump_suspects(scene, check)
    by_name = PoseCheck()
    flagged = _jump_suspects(scene, by_name)
    rest = [i for i, f in enumerate(scene.frames) if f.name not in flagged]
    if flagged and not by_name.skipped and np.array_equal(_neighbour_order(C[rest]), np.arange(len(rest))):
        return by_name, flagged
    check.order = "file names do not follow the capture order; neighbours taken by camera position"
    return check, _jump_suspects(scene.subset(list(order)), check)


def _jump_suspects(scene: Scene, check: PoseCheck) -> dict[str, list[str]]:
    """Photos (frames in neighbour order) that disagree with the capture's main group -> their reasons."""
    n = len(scene)
    Rs = np.stack([f.pose.R for f in scene.frames])
    C = scene.centers()
    rots = np.array([_rot_between(Rs, i, i + 1) for i in range(n - 1)])
    steps = np.linalg.norm(np.diff(C, axis=0), axis=1)
    check.median_rot_deg, check.median_step = float(np.median(rots)), float(np.median(steps))
    check.rot_limit_deg = min(max(K * check.median_rot_deg, ROT_FLOOR_DEG), ROT_CAP_DEG)
    check.step_limit = max(K * check.median_step, STEP_FLOOR * scene.scale())
    jumps = int(np.sum((rots > check.rot_limit_deg) | (steps > check.step_limit)))
    if jumps > (n - 1) / 4:
        check.skipped = (
            f"{jumps} of {n - 1} neighbour steps are jumps: the photos do not follow one path, "
            "so the jump check was skipped"
        )
        return {}
    groups = _linked_groups(Rs, C, check.rot_limit_deg, check.step_limit, check.median_rot_deg, check.median_step)
    out: dict[str, list[str]] = {}
    for g in groups[1:]:
        if len(g) <= n / 4:
            for i in g:
                out[scene.frames[i].name] = _jump_reasons(scene, Rs, C, i, check)
        else:
            a = g[0] - 1 if g[0] > 0 else g[-1] + 1
            check.breaks.append(
                f"{scene.frames[min(a, g[0])].name} -> {scene.frames[max(a, g[0])].name}: "
                f"views {_rot_between(Rs, a, g[0]):.0f} deg apart (median step "
                f"{check.median_rot_deg:.1f} deg)"
            )
    return out


def _stat_reasons(stats: list[ImageStats]) -> dict[str, list[str]]:
    if len(stats) < 4:
        return {}
    med_err = float(np.median([s.mean_reprojection_error for s in stats]))
    med_track = float(np.median([s.mean_track_length for s in stats]))
    out: dict[str, list[str]] = {}
    for s in stats:
        if s.mean_reprojection_error > max(ERR_K * med_err, ERR_FLOOR_PX):
            out.setdefault(s.name, []).append(
                f"reprojection error {s.mean_reprojection_error:.2f} px (median {med_err:.2f})"
            )
        if s.mean_track_length < min(TRACK_K * med_track, TRACK_FLOOR):
            out.setdefault(s.name, []).append(
                f"short tracks: its points are seen by {s.mean_track_length:.1f} photos (median {med_track:.1f})"
            )
    return out


# ---- the camera itself ---------------------------------------------------------------------------------------


def camera_warnings(cam: Camera, exif_focal_px: float | None = None) -> list[str]:
    """Sentences about an implausible camera: a field of view whose wider side is out of [FOV_MIN_DEG,
    FOV_MAX_DEG] degrees, or a focal length far from the EXIF one (``exif_focal_px``, at the camera's
    resolution)."""
    fh, fv = cam.fov_deg
    out = []
    if not FOV_MIN_DEG <= max(fh, fv) <= FOV_MAX_DEG:
        out.append(
            f"recovered camera is implausible: fx={cam.fx:.0f} px for {cam.width}x{cam.height} photos is a "
            f"{fh:.1f} x {fv:.1f} deg field of view (phones and most lenses see 30-100 deg)"
        )
    if exif_focal_px and not (1 / FOCAL_RATIO <= cam.fx / exif_focal_px <= FOCAL_RATIO):
        from sparself.core.geometry import fov_deg

        out.append(
            f"recovered focal length fx={cam.fx:.0f} px ({fh:.1f} deg) is far from the photos' EXIF focal "
            f"length {exif_focal_px:.0f} px ({fov_deg(cam.width, exif_focal_px):.1f} deg)"
        )
    return out


def mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotations (N, 3, 3) -> (3, 3): the SO(3) projection of their sum."""
    U, _, Vt = np.linalg.svd(Rs.sum(0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def compare_poses(est: Scene, ref: Scene) -> dict:
    """Compare the poses of two scenes of the same images (matched by frame name) up to a similarity.

    translation: the estimated camera centres are aligned to the reference ones with a similarity
      (Umeyama, :func:`geometry.align_similarity`); error = distance between aligned and reference centres,
      absolute and relative to the reference scale (median distance of its centres to their mean).
    rotation: angle between each reference camera rotation and the estimated one after the best global
      rotation (chordal mean of R_ref^T R_est) -- this does not depend on how well the centres constrain
      the alignment, which is weak for a short arc of cameras. ``rot_deg_*_centres`` uses the rotation of
      the centre alignment instead.
    -> dict(n, rot_deg_mean, rot_deg_max, rot_deg_mean_centres, rot_deg_max_centres, trans_mean, trans_max,
            trans_rel_mean, trans_rel_max, scale, missing: names in ref but not in est).
    """
    by_name = {f.name: f for f in est.frames}
    idx = [i for i, f in enumerate(ref.frames) if f.name in by_name]
    if len(idx) < 3:
        raise ValueError(f"only {len(idx)} frames in common; need 3 to align")
    common = [ref.frames[i] for i in idx]
    Re = np.stack([by_name[f.name].pose.R for f in common])
    Rr = np.stack([f.pose.R for f in common])
    Ce = np.stack([by_name[f.name].pose.center for f in common])
    Cr = np.stack([f.pose.center for f in common])
    s, R, t = align_similarity(Ce, Cr)
    terr = np.linalg.norm((s * (R @ Ce.T)).T + t - Cr, axis=1)
    # x_cam = R_est X_est = R_ref (G X_est)  =>  G ~ R_ref^T R_est
    G = mean_rotation(np.einsum("nji,njk->nik", Rr, Re))
    rerr = np.array([float(rotation_angle_deg(a @ G.T, b)) for a, b in zip(Re, Rr)])
    rerr_c = np.array([float(rotation_angle_deg(a @ R.T, b)) for a, b in zip(Re, Rr)])
    scale = ref.subset(idx).scale()
    return {
        "n": len(common),
        "rot_deg_mean": float(rerr.mean()),
        "rot_deg_max": float(rerr.max()),
        "rot_deg_mean_centres": float(rerr_c.mean()),
        "rot_deg_max_centres": float(rerr_c.max()),
        "trans_mean": float(terr.mean()),
        "trans_max": float(terr.max()),
        "trans_rel_mean": float(terr.mean() / scale),
        "trans_rel_max": float(terr.max() / scale),
        "scale": scale,
        "missing": [f.name for f in ref.frames if f.name not in by_name],
    }
