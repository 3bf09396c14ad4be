"""Plan files (``plan.json``): reading one back with every check (format, the scene it was made for, names,
finite poses, indices), and the names of planned frames."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sparself.capture.images import IMAGE_EXTENSIONS
from sparself.capture.scene import Frame, Scene
from sparself.core.errors import InputError
from sparself.core.geometry import Pose
from sparself.core.names import check_names

PLAN_FORMAT = "sparself-plan"


PLAN_VERSION = 1


def source_record(scene: Scene) -> dict:
    """What identifies the source scene in a plan file: its views' names and where its cameras are."""
    return {
        "source_frames": [f.name for f in scene.frames],
        "source_center": [float(v) for v in scene.centers().mean(0)],
        "source_scale": float(scene.scale()),
    }


@dataclass(frozen=True)
class PlanSource:
    """What a plan file says of the scene it was made on, read without checking the file (:func:`load_plan`
    checks it): its views' names, their number and the order the plan followed, each None when not recorded."""

    names: tuple[str, ...] | None = None
    n_views: int | None = None
    order: str | None = None


def plan_source(path: Path) -> PlanSource:
    """The :class:`PlanSource` of a plan file; empty when the file cannot be read (:func:`load_plan` says why)."""
    try:
        doc = json.loads(Path(path).read_text(), parse_constant=reject_constant)
    except (OSError, ValueError):
        return PlanSource()
    if not isinstance(doc, dict):
        return PlanSource()
    names, n, cfg = doc.get("source_frames"), doc.get("n_source_views"), doc.get("config")
    order = cfg.get("order") if isinstance(cfg, dict) else None
    return PlanSource(
        tuple(map(str, names)) if isinstance(names, list) else None,
        n if isinstance(n, int) else None,
        order if isinstance(order, str) else None,
    )


def check_plan_source(path: Path, doc: dict, scene: Scene) -> None:
    """Refuse a plan made for another scene: other views, other cameras, or indices the scene lacks."""
    src = doc.get("source") or "another scene"
    names, n = doc.get("source_frames"), doc.get("n_source_views")
    if isinstance(n, int) and n != len(scene):
        raise InputError(
            f"{path}: plan was made for {n} views ({src}), this scene has {len(scene)} "
            f"({scene.source}); make a new plan with `sparself plan`"
        )
    if isinstance(names, list) and sorted(map(str, names)) != sorted(f.name for f in scene.frames):
        odd = sorted(set(map(str, names)) ^ {f.name for f in scene.frames})
        raise InputError(
            f"{path}: plan was made for other views ({src}; in only one of the two: "
            f"{', '.join(odd[:3])}{', ...' if len(odd) > 3 else ''}); make a new plan for "
            f"{scene.source} with `sparself plan`"
        )
    c, sc = doc.get("source_center"), doc.get("source_scale")
    if isinstance(c, list) and isinstance(sc, (int, float)) and len(c) == 3 and len(scene) > 0:
        try:
            c, sc = np.asarray(c, float), float(sc)
        except (TypeError, ValueError, OverflowError):
            raise InputError(f"{path}: source_center/source_scale are not numbers") from None
        moved = float(np.linalg.norm(c - scene.centers().mean(0)))
        if moved > 1e-3 * max(float(sc), 1e-12) or abs(float(sc) - scene.scale()) > 1e-3 * max(float(sc), 1e-12):
            raise InputError(
                f"{path}: plan was made for cameras elsewhere ({src}): same view names, other "
                f"poses; make a new plan for {scene.source} with `sparself plan`"
            )
    for cid, rec in (doc.get("cameras") or {}).items():
        cam = scene.cameras.get(int(cid)) if str(cid).isdigit() else None
        if (
            cam is not None
            and isinstance(rec, dict)
            and (rec.get("width"), rec.get("height")) != (cam.width, cam.height)
        ):
            raise InputError(
                f"{path}: plan's camera {cid} is {rec.get('width')}x{rec.get('height')}, the scene's "
                f"is {cam.width}x{cam.height} ({scene.source}); make a new plan with `sparself plan`"
            )


def check_indices(path: Path, frames: list[Frame], scene: Scene) -> None:
    """Planned indices must lie among (or just past) the scene's: a plan for a longer capture does not."""
    own = np.array([f.index for f in scene.frames], dtype=np.float64)
    if not len(own) or not frames:
        return
    lo, hi = own.min(), own.max()
    span = max(hi - lo, 1.0)
    bad = [f for f in frames if not lo - span <= f.index <= hi + span]
    if bad:
        raise InputError(
            f"{path}: planned index {bad[0].index:g} ({bad[0].name}) is far outside this scene's "
            f"views {lo:g}..{hi:g}: the plan was made for another scene"
        )


def reject_constant(name: str):
    raise ValueError(f"non-finite number {name}")


def vector(path: Path, i: int, rec: dict, key: str, n: int) -> np.ndarray:
    try:
        v = np.asarray(rec[key], dtype=np.float64)
    except KeyError:
        raise InputError(f"{path}: frame {i} has no {key!r}") from None
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{path}: frame {i}: {key} is not a list of numbers") from None
    if v.size != n:
        raise InputError(f"{path}: frame {i}: {key} must have {n} numbers, got {v.size}")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{path}: frame {i}: {key} contains NaN or inf")
    return v.reshape(-1)


def load_plan(path: Path, scene: Scene, *, check_source: bool = True) -> list[Frame]:
    """Read a plan written by :func:`save_plan`; camera ids must exist in ``scene``.

    Raises InputError naming the file on unreadable or invalid JSON, an unknown version, no frames,
    NaN/inf, wrong shapes, unknown cameras, or a c2w that disagrees with qvec/tvec (someone edited one and
    not the other). check_source: also refuse a plan made for another scene (other number of views, view
    names, camera poses or image size, as recorded by :func:`save_plan`; indices far outside the scene's).
    A plan without a version (written by hand) is read as version 1.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text(), parse_constant=reject_constant)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text (JSON) file") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: invalid JSON ({e.msg} at line {e.lineno}, column {e.colno})") from None
    except ValueError as e:
        raise InputError(f"{path}: invalid plan ({e})") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    if not isinstance(doc, dict) or doc.get("format") != PLAN_FORMAT or not isinstance(doc.get("frames"), list):
        raise InputError(f"{path}: not a sparself plan (expected format {PLAN_FORMAT!r} with a 'frames' list)")
    if doc.get("version", PLAN_VERSION) != PLAN_VERSION:
        raise InputError(
            f"{path}: plan version {doc.get('version')!r} is not one this sparself reads "
            f"(version {PLAN_VERSION}); make the plan again with `sparself plan`"
        )
    if not doc["frames"]:
        raise InputError(
            f"{path}: the plan has no frames, so there is nothing to synthesize "
            "(make it with --n-mid or --n-extra above 0)"
        )
    if check_source:
        check_plan_source(path, doc, scene)
    frames = [plan_frame(path, i, rec, scene) for i, rec in enumerate(doc["frames"])]
    # planned names become files beside the scene's own images: checked before anything is written
    check_names([f.name for f in frames], path, what="frame name", extensions=IMAGE_EXTENSIONS)
    if check_source:
        check_indices(path, frames, scene)
    return frames


def plan_frame(path: Path, i: int, rec: object, scene: Scene) -> Frame:
    """Frame ``i`` of a plan file, every field checked (InputError naming the file and the frame)."""
    if not isinstance(rec, dict):
        raise InputError(f"{path}: frame {i} is not an object")
    q = vector(path, i, rec, "qvec", 4)
    t = vector(path, i, rec, "tvec", 3)
    if np.linalg.norm(q) < 1e-9:
        raise InputError(f"{path}: frame {i}: qvec is zero")
    try:
        pose = Pose(q, t)
        pose.R  # normalises qvec: fails when its norm overflows
    except ValueError:
        raise InputError(f"{path}: frame {i}: qvec is not a usable rotation") from None
    if "c2w" in rec:
        c2w = vector(path, i, rec, "c2w", 12).reshape(3, 4)
        if np.abs(c2w - pose.c2w()[:3]).max() > 1e-6:
            raise InputError(f"{path}: frame {i}: c2w disagrees with qvec/tvec (edit both, or drop c2w)")
    try:
        index = float(rec["index"])
        cam = int(rec.get("camera_id", 1))
    except (KeyError, TypeError, ValueError, OverflowError):
        raise InputError(f"{path}: frame {i}: missing or non-numeric index/camera_id") from None
    if not math.isfinite(index):
        raise InputError(f"{path}: frame {i}: index is not finite")
    if cam not in scene.cameras:
        raise InputError(f"{path}: frame {i}: camera {cam} is not a camera of the scene (has {sorted(scene.cameras)})")
    name = rec.get("name") or novel_name(index)
    return Frame(name=name, pose=pose, camera_id=cam, index=index, path=None, synthetic=True)


def novel_name(index: float) -> str:
    """File name of a planned view: ``novel_0003.50.png`` for index 3.5. It sorts by index only for
    index >= 0; the written dense scene prefixes a rank (``sparself.capture.io.dense.rank_names``) so that
    names sort in its order for any index."""
    return f"novel_{index:07.2f}.png"
