"""Scene, Camera, Frame: a capture's images, intrinsics and poses in ONE convention (COLMAP world-to-camera).

Image decoding lives here, once: EXIF orientation is applied, grayscale / RGBA / 16-bit images become
RGB float32 in [0, 1], and any unreadable file raises :class:`InputError` naming it.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable, Literal, Sequence

import numpy as np

from sparself.capture.images import load_image, read_mask, resize_image, some
from sparself.core.errors import InputError
from sparself.core.geometry import Pose, fov_deg, intrinsics_matrix
from sparself.core.lens import distortion_shift, pinhole_matrix, undistort_image, undistort_points

log = logging.getLogger(__name__)

SourceFormat = Literal["", "colmap", "llff", "nerfstudio", "middlebury", "sfm"]

# fewer sparse points than this are not used: 3DGS starts from random points instead, and triangulation that
# finds fewer leaves a scene without points
MIN_POINTS = 100


# Parameter layouts of the COLMAP camera models we read: (fx, fy, cx, cy) are taken from these.
_PINHOLE_LIKE = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "SIMPLE_RADIAL_FISHEYE": ("f", "cx", "cy", "k"),
    "RADIAL_FISHEYE": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}


@dataclass(frozen=True)
class Camera:
    """Intrinsics of one physical camera, with COLMAP's model name and parameter order.

    The maths here are pinhole: a camera with distortion parameters is read as the pinhole camera of its
    undistorted photos (:func:`undistorted`), unless its distortion is negligible or not trusted.
    """

    model: str
    width: int
    height: int
    params: tuple[float, ...]

    def __post_init__(self) -> None:
        if self.model not in _PINHOLE_LIKE:
            raise ValueError(f"unsupported camera model {self.model!r}")
        names = _PINHOLE_LIKE[self.model]
        if len(self.params) != len(names):
            raise ValueError(f"{self.model} needs {len(names)} parameters, got {len(self.params)}")
        if not np.all(np.isfinite(self.params)):
            raise ValueError("camera parameters contain NaN or inf")
        object.__setattr__(self, "params", tuple(float(p) for p in self.params))

    def _get(self, name: str) -> float:
        return self.params[_PINHOLE_LIKE[self.model].index(name)]

    @property
    def fx(self) -> float:
        return self._get("f") if "f" in _PINHOLE_LIKE[self.model] else self._get("fx")

    @property
    def fy(self) -> float:
        return self._get("f") if "f" in _PINHOLE_LIKE[self.model] else self._get("fy")

    @property
    def cx(self) -> float:
        return self._get("cx")

    @property
    def cy(self) -> float:
        return self._get("cy")

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsics matrix."""
        return intrinsics_matrix(self.fx, self.fy, self.cx, self.cy)

    @property
    def fov_deg(self) -> tuple[float, float]:
        """(horizontal, vertical) field of view in degrees."""
        return fov_deg(self.width, self.fx), fov_deg(self.height, self.fy)

    @classmethod
    def pinhole(
        cls,
        width: int,
        height: int,
        fx: float,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
    ) -> "Camera":
        """A PINHOLE camera; the principal point defaults to the image centre."""
        fy = fx if fy is None else fy
        cx = width / 2.0 if cx is None else cx
        cy = height / 2.0 if cy is None else cy
        return cls("PINHOLE", int(width), int(height), (fx, fy, cx, cy))

    @property
    def lens(self) -> tuple[np.ndarray, bool] | None:
        """OpenCV's distortion coefficients of the model and whether it is a fisheye model
        (:mod:`sparself.core.lens`), or None for a pinhole model."""
        names = _PINHOLE_LIKE[self.model]
        if self.model in ("SIMPLE_PINHOLE", "PINHOLE"):
            return None
        fisheye = self.model.endswith("FISHEYE")
        order = ("k1", "k2", "k3", "k4") if fisheye else ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
        given = {("k1" if n == "k" else n): p for n, p in zip(names, self.params)}
        return np.array([given.get(n, 0.0) for n in order]), fisheye

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for images resampled to (width, height): focal and centre scale per axis.

        Follows the pixel-corner convention (COLMAP's): a pixel centre x maps to (x + 0.5) s - 0.5
        only approximately; we scale the principal point by s, as COLMAP's own image undistorter does.
        """
        sx, sy = width / self.width, height / self.height
        return Camera.pinhole(width, height, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy)


@dataclass(frozen=True)
class Undistortion:
    """One camera's photos as sparself reads them: taken through ``lens`` (a model with distortion), seen as
    the pinhole camera ``pinhole`` of the same size (:func:`undistorted`)."""

    lens: Camera
    pinhole: Camera

    def _model(self) -> tuple[np.ndarray, np.ndarray, bool]:
        D, fisheye = self.lens.lens or (np.zeros(4), False)
        return self.lens.K, D, fisheye

    def image(self, img: np.ndarray, path: Path | None = None) -> np.ndarray:
        """(H, W, C) or (H, W) photo at the lens camera's size -> its pinhole image, same size."""
        if (img.shape[1], img.shape[0]) != (self.lens.width, self.lens.height):
            raise InputError(
                f"{path or 'image'}: image is {img.shape[1]}x{img.shape[0]} but its camera says "
                f"{self.lens.width}x{self.lens.height}"
            )
        K, D, fisheye = self._model()
        return undistort_image(img, K, D, fisheye, self.pinhole.K)

    def points(self, xy: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """(M, 2) keypoints in a photo of size (W, H) -> the same rays in its pinhole image of that size."""
        s = np.array([self.lens.width / size[0], self.lens.height / size[1]])
        K, D, fisheye = self._model()
        return undistort_points(np.asarray(xy, np.float64) * s, K, D, fisheye, self.pinhole.K) / s


@dataclass
class Frame:
    """One image of a scene: its pose, its camera, its place in the capture order.

    index: position in capture order; fractional for planned (novel) poses, e.g. 3.5 between 3 and 4.
    path: the image file, or None for a pose without a photo (a planned view before synthesis).
    image: an in-memory image (H, W, 3) float32 in [0, 1], used instead of ``path`` when set
           (synthesized views before they are written).
    confidence: a synthesized view's per-pixel confidence (H, W) in [0, 1], written as ``masks/``.
    mask: a mask file holding the confidence (8-bit, value / 255: nerfstudio's ``mask_path``, sparself's
          ``masks/``), as read back from a scene; decoded only when used (:meth:`Scene.confidence_map`),
          so that a megapixel scene does not hold every map in memory. ``confidence`` wins when both are set.
    weight: the frame's loss weight in the in-project reconstructors (in memory only; the evaluation sets it on
            synthesized frames): each pixel counts ``weight`` x its confidence (see :meth:`Scene.pixel_weight`).
    """

    name: str
    pose: Pose
    camera_id: int = 1
    index: float = 0.0
    path: Path | None = None
    image: np.ndarray | None = None
    synthetic: bool = False
    confidence: np.ndarray | None = None
    mask: Path | None = None
    weight: float = 1.0


@dataclass(frozen=True)
class Observations:
    """One image's 2D-3D correspondences (its SfM track elements), kept in ``Scene.observations``
    by frame name so that a written model keeps them.

    point: (M,) indices into ``Scene.points``; xy: (M, 2) pixel positions (COLMAP convention) in an image
    of ``size`` = (W, H), scaled when the camera was resized."""

    point: np.ndarray
    xy: np.ndarray
    size: tuple[int, int]


def points_depth_range(points: np.ndarray, poses: list[Pose]) -> tuple[float, float] | None:
    """(near, far) depth of sparse points (P, 3) in front of cameras at ``poses``: their 1st / 99th
    percentiles widened by 10 %; None under 10 depths. A few dozen points bound the depth well where they
    are too few to start a reconstruction from (a guess from the camera layout can be 4x off)."""
    if len(points) < 10:
        return None
    depths = [z[z > 0] for z in ((points @ p.R.T + p.tvec)[:, 2] for p in poses)]
    z = np.concatenate(depths) if depths else np.zeros(0)
    if len(z) < 10:
        return None
    near, far = np.percentile(z, 1) * 0.9, np.percentile(z, 99) * 1.1
    return float(max(near, 1e-3)), float(max(far, near * 1.5))


@dataclass
class Scene:
    """A capture: cameras (by id), frames in capture order, optional depth bounds and sparse points.

    bounds: (near, far) scene depth range over all cameras, if known (LLFF stores it; COLMAP points give it).
    points: (P, 3) sparse world points, if known; point_colors: their (P, 3) uint8 colours, if known.
    observations: each frame's keypoints in the points' tracks, by frame name (what a written COLMAP model keeps).
    source_format: the format the scene was read from ("" for a scene made in memory).
    unregistered: photos of the capture without a pose (a COLMAP model's images that SfM did not register).
    frame_bounds: per-view (near, far) by frame name, where the files give them (LLFF).
    undistort: cameras (by id) whose photos are undistorted when loaded (:func:`undistorted`); ``cameras``
               then holds their pinhole cameras.
    """

    cameras: dict[int, Camera]
    frames: list[Frame]
    bounds: tuple[float, float] | None = None
    points: np.ndarray | None = None
    source: Path | None = None
    point_colors: np.ndarray | None = None
    observations: dict[str, Observations] = field(default_factory=dict)
    source_format: SourceFormat = ""
    unregistered: tuple[str, ...] = ()
    frame_bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    undistort: dict[int, Undistortion] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for f in self.frames:
            if f.camera_id not in self.cameras:
                raise ValueError(f"frame {f.name} refers to unknown camera {f.camera_id}")

    def __len__(self) -> int:
        return len(self.frames)

    # ---- poses -------------------------------------------------------------------------------
    @property
    def poses(self) -> list[Pose]:
        return [f.pose for f in self.frames]

    def camera(self, i: int) -> Camera:
        """The camera of frame i."""
        return self.cameras[self.frames[i].camera_id]

    def centers(self) -> np.ndarray:
        """(N, 3) camera centres."""
        return np.stack([f.pose.center for f in self.frames]) if self.frames else np.zeros((0, 3))

    def c2w(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world matrices (OpenCV camera axes)."""
        return np.stack([f.pose.c2w() for f in self.frames])

    def w2c(self) -> np.ndarray:
        """(N, 4, 4) world-to-camera matrices."""
        return np.stack([f.pose.w2c() for f in self.frames])

    def scale(self) -> float:
        """A length scale of the capture: the median distance of camera centres to their mean (>0)."""
        c = self.centers()
        d = np.linalg.norm(c - c.mean(0), axis=1)
        s = float(np.median(d)) if len(d) else 1.0
        return s if s > 1e-9 else 1.0

    def depth_bounds(self) -> tuple[float, float]:
        """(near, far) scene depth. From ``bounds`` if known, else from the sparse points seen in front
        of the cameras (1st/99th percentile), else a guess from the camera layout (logged)."""
        if self.bounds is not None:
            return float(self.bounds[0]), float(self.bounds[1])
        seen = None if self.points is None else points_depth_range(self.points, self.poses)
        if seen is not None:
            return seen
        # Cameras looking at a common centre: the scene lies around the centroid of the centres.
        dist = float(np.median(np.linalg.norm(self.centers() - self.centers().mean(0), axis=1)))
        dist = dist if dist > 1e-9 else 1.0
        log.warning("scene has no depth bounds or sparse points; guessing near/far from camera layout")
        return 0.2 * dist, 5.0 * dist

    # ---- images ------------------------------------------------------------------------------
    def image(self, i: int, size: tuple[int, int] | None = None) -> np.ndarray:
        """Image of frame i as (H, W, 3) float32 in [0, 1], optionally resized to size = (W, H)."""
        f = self.frames[i]
        if f.image is not None:
            img = f.image
            if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
                img = resize_image(img, size)
            return img
        if f.path is None:
            raise InputError(f"frame {f.name} has no image (a planned pose that was not synthesized)")
        cam = self.camera(i)
        lens = self.undistort.get(f.camera_id)
        img = load_image(f.path, size=None if lens else size)
        if lens is not None:  # undistorted at the photo's own size, before any resize
            img = lens.image(img, f.path)
            if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
                img = resize_image(img, size)
        if size is None and (img.shape[1], img.shape[0]) != (cam.width, cam.height):
            raise InputError(
                f"{f.path}: image is {img.shape[1]}x{img.shape[0]} but its camera says {cam.width}x{cam.height}"
            )
        return img

    def images(self, size: tuple[int, int] | None = None, indices: Iterable[int] | None = None) -> np.ndarray:
        """(N, H, W, 3) float32 images (all frames, or ``indices``), optionally resized to size = (W, H)."""
        idx = range(len(self.frames)) if indices is None else list(indices)
        return np.stack([self.image(i, size) for i in idx])

    # ---- derived scenes ----------------------------------------------------------------------
    def subset(self, indices: Sequence[int]) -> "Scene":
        """A scene with only the given frames (in the given order); cameras and bounds are shared."""
        frames = [self.frames[i] for i in indices]
        return replace(self, frames=frames)

    def without(self, positions: Sequence[int]) -> "Scene":
        """The scene minus the frames at ``positions`` (a hold-out), the others in their order."""
        drop = set(positions)
        return self.subset([i for i in range(len(self)) if i not in drop])

    def resized(self, max_side: int) -> "Scene":
        """The scene at a lower resolution: cameras scaled so their longer side is ``max_side`` pixels.

        Images are resized when loaded through :meth:`image` with :meth:`image_size`.
        """
        cams = {}
        for cid, cam in self.cameras.items():
            s = max_side / max(cam.width, cam.height)
            w, h = max(1, int(round(cam.width * s))), max(1, int(round(cam.height * s)))
            cams[cid] = cam.resized(w, h)
        return replace(self, cameras=cams)

    def image_size(self, i: int = 0) -> tuple[int, int]:
        """(W, H) of frame i's camera."""
        c = self.camera(i)
        return c.width, c.height

    def load(self, i: int) -> np.ndarray:
        """Image of frame i at its camera's size (resizing when the scene was :meth:`resized`)."""
        return self.image(i, self.image_size(i))

    def confidence_map(self, i: int) -> np.ndarray | None:
        """Frame i's confidence (H, W) float32 at the size it was made or stored at: its in-memory
        ``confidence``, else its ``mask`` file (value / 255, :func:`read_mask`), else None (no map)."""
        f = self.frames[i]
        if f.confidence is not None:
            return np.asarray(f.confidence, np.float32)
        if f.mask is None:
            return None
        conf = np.divide(read_mask(f.mask), 255.0, dtype=np.float32)
        lens = self.undistort.get(f.camera_id)
        return conf if lens is None else np.clip(lens.image(conf, f.mask), 0.0, 1.0)

    def pixel_weight(self, i: int) -> np.ndarray | None:
        """Frame i's per-pixel loss weight (H, W) at its camera's size: its ``weight`` x its confidence map
        (:meth:`confidence_map`); None when every pixel counts 1 (weight 1, no map), so reconstructors keep
        their plain loss."""
        f = self.frames[i]
        if f.confidence is None and f.mask is None and f.weight == 1.0:
            return None
        w, h = self.image_size(i)
        conf = self.confidence_map(i)
        if conf is None:
            return np.full((h, w), f.weight, np.float32)
        if f.confidence is not None:  # a map made in memory may hold NaN or go past [0, 1]; a mask's cannot
            conf = np.clip(np.nan_to_num(conf), 0.0, 1.0)
        if conf.shape != (h, w):
            conf = np.clip(resize_image(conf, (w, h)), 0.0, 1.0)
        return (f.weight * conf).astype(np.float32, copy=False)

    def load_all(self) -> np.ndarray:
        """(N, H, W, 3) images at the cameras' size. All frames must share one image size."""
        sizes = {self.image_size(i) for i in range(len(self))}
        if len(sizes) > 1:
            raise InputError(f"frames have different image sizes {sorted(sizes)}; resize the scene first")
        return np.stack([self.load(i) for i in range(len(self))])


# ---- image files -------------------------------------------------------------------------------


# ---- conversions to upright 8/32-bit RGB: what they are, said once per folder with a count ----------------


def one_size(scene: Scene) -> Scene:
    """Mixed image sizes: the scene with every camera resized to the most common size (with a warning),
    so that training and synthesis see one image size; different aspect ratios are refused (InputError)."""
    sizes = {(c.width, c.height) for c in scene.cameras.values()}
    if len(sizes) <= 1:
        return scene
    counts = Counter(scene.image_size(i) for i in range(len(scene)))
    w, h = max(sizes, key=lambda s: (counts.get(s, 0), s))
    if any(abs(cw * h - ch * w) > 0.01 * ch * w for cw, ch in sizes):
        raise InputError(
            f"{scene.source or 'scene'}: views have different aspect ratios "
            f"({', '.join(f'{a}x{b}' for a, b in sorted(sizes))}); use photos of one shape"
        )
    log.warning(
        "%s: views have different image sizes (%s); resizing them to %dx%d",
        scene.source or "scene",
        ", ".join(f"{a}x{b}" for a, b in sorted(sizes)),
        w,
        h,
    )
    return replace(
        scene,
        cameras={cid: c if (c.width, c.height) == (w, h) else c.resized(w, h) for cid, c in scene.cameras.items()},
    )


# a camera whose pinhole reading errs by at most this (px) is kept as it is: undistorting would only resample
MAX_LENS_SHIFT = 0.25
# an undistortion that would crop the photos' view by more than this is not trusted: a distortion that strong is
# what SfM fits to a few views' keypoints near the centre, not what lenses do
MAX_LENS_CROP = 0.15


def _pinhole_view(cam: Camera) -> tuple[Camera | None, float]:
    """(the pinhole camera of ``cam``'s undistorted photos, or None where a pinhole reading errs by at most
    ``MAX_LENS_SHIFT``; the farthest the distortion moves a pixel, px)."""
    if cam.lens is None:
        return None, 0.0
    D, fisheye = cam.lens
    shift = distortion_shift(cam.K, D, fisheye, (cam.width, cam.height))
    if shift <= MAX_LENS_SHIFT:
        return None, shift
    K = pinhole_matrix(cam.K, D, fisheye, (cam.width, cam.height))
    return Camera("PINHOLE", cam.width, cam.height, (K[0, 0], K[1, 1], K[0, 2], K[1, 2])), shift


def undistorted(scene: Scene) -> Scene:
    """The scene seen through pinhole cameras, which is what sparself's geometry assumes.

    A camera whose distortion moves some pixel by more than ``MAX_LENS_SHIFT`` is replaced by the pinhole
    camera of its undistorted photos (:func:`sparself.core.lens.pinhole_matrix`: same size and principal
    point, the widest view without blank corners); its frames' photos are undistorted when loaded and their
    keypoints move with them. Poses and points are unchanged. Other cameras are kept as they are, and so is one
    whose pinhole view would lose more than ``MAX_LENS_CROP`` of its focal length to the crop (with a warning)."""
    lenses: dict[int, Undistortion] = {}
    shifts: list[float] = []
    untrusted: list[tuple[int, float]] = []
    for cid, cam in scene.cameras.items():
        pin, shift = _pinhole_view(cam)  # None for a camera already undistorted: it is a pinhole one
        if pin is None:
            continue
        if pin.fx > cam.fx * (1 + MAX_LENS_CROP):
            untrusted.append((cid, cam.fx / pin.fx))
            continue
        lenses[cid] = Undistortion(cam, pin)
        shifts.append(shift)
    _say_lenses(scene, lenses, shifts, untrusted)
    if not lenses:
        return scene
    cam_of = {f.name: f.camera_id for f in scene.frames}
    obs = {
        name: replace(o, xy=lenses[cam_of[name]].points(o.xy, o.size)) if cam_of.get(name) in lenses else o
        for name, o in scene.observations.items()
    }
    cameras = {cid: lenses[cid].pinhole if cid in lenses else cam for cid, cam in scene.cameras.items()}
    return replace(scene, cameras=cameras, observations=obs, undistort={**scene.undistort, **lenses})


def _say_lenses(
    scene: Scene, lenses: dict[int, Undistortion], shifts: list[float], untrusted: list[tuple[int, float]]
) -> None:
    """One line for the cameras undistorted, one warning for those read as pinhole against their files."""
    where = scene.source or "scene"
    if lenses:
        models = ", ".join(sorted({u.lens.model for u in lenses.values()}))
        before, after = [u.lens.fx for u in lenses.values()], [u.pinhole.fx for u in lenses.values()]
        log.info(
            "%s: %d camera(s) (%s) bend pixels by up to %.1f px; their photos are read undistorted, as pinhole "
            "cameras (focal %.1f -> %.1f px%s)",
            where,
            len(lenses),
            models,
            max(shifts),
            before[0],
            after[0],
            "" if len(lenses) == 1 else " for the first",
        )
    if untrusted:
        log.warning(
            "%s: undistorting %d camera(s) (%s) would crop their view to %.0f %% of its focal length, which no "
            "common lens does; they are read as pinhole cameras (their distortion is probably poorly determined "
            "by these photos)",
            where,
            len(untrusted),
            some([str(cid) for cid, _ in untrusted]),
            100 * min(r for _, r in untrusted),
        )


def preloaded(scene: Scene) -> Scene:
    """The scene with every frame's image decoded at its camera's size and held in memory (so a resized
    scene writes resized images, and every consumer sees the same pixels)."""
    return replace(scene, frames=[replace(f, image=scene.load(i)) for i, f in enumerate(scene.frames)])
