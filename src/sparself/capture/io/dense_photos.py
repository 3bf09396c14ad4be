"""A dense scene read back as the capture it was made from, so that the run trained for it can synthesize
more views from it (``sparself synthesize OUT/run --scene OUT/scene``).

What was written differs from what the run was trained on in three ways, each undone here from
``sparself.json``:

* **Synthesized frames are in it.** A synthesized view is never a source: they are dropped.
* **Names carry a rank prefix** (``0007_IMG_3.jpg``). Each photo gets back its ``source_name``, the name the
  run's training views were recorded with.
* **Indices count every written frame.** A scene read from files gets index = position in name order,
  synthesized frames included. The photos get back the index the run gave them, which ``sparself.json``
  records (for a capture planned in capture order: 0..N-1 in capture order, as reading the original capture
  gives), and a plan made on the dense scene is mapped to that scale through every written frame's recorded
  index (:meth:`DensePhotos.capture_index`).

The run's holdout positions count along the order it trained in: the photos by the index ``sparself.json``
records for them (:meth:`DensePhotos.held_out`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from sparself.capture.io.dense import FORMAT, SPARSELF_JSON
from sparself.capture.scene import Scene
from sparself.core.errors import InputError
from sparself.core.names import capture_key, check_names

RUN_FOLDER, SCENE_FOLDER = "run", "scene"  # densify's layout: OUT/run beside OUT/scene


@dataclass(frozen=True)
class WrittenFrame:
    """One frame as ``sparself.json`` records it: its written name, whether it was synthesized, its index on the
    scale the run used, and the name it had before writing."""

    name: str
    synthetic: bool
    index: float
    source_name: str


@dataclass(frozen=True)
class DensePhotos:
    """The photos of a dense scene as the capture they came from.

    scene: the photos only, named as the user named them, in capture order, each with the index the run gave
        it; images, poses, cameras and the photos' tracks from the dense scene.
    dense: the dense scene as read (every frame, written names, index = position in name order): what
        ``sparself plan`` on the dense scene plans on.
    trained: the photos' names in the order the run trained in (by recorded index): its holdout counts along it.
    anchors: (index in ``dense``, recorded index) of every written frame, in ``dense`` order.
    record: the ``sparself.json`` these come from (named in every message).
    """

    scene: Scene
    dense: Scene
    trained: tuple[str, ...]
    anchors: tuple[tuple[float, float], ...]
    record: Path

    def held_out(self, positions: Sequence[int], n_trained: int) -> list[int]:
        """Positions in :attr:`scene` of the photos at ``positions`` of the order the run trained in; none when
        the scene holds only the run's ``n_trained`` training photos (a scene ``synthesize`` wrote leaves the
        held-out photos out)."""
        if len(self.trained) == n_trained:
            return []
        bad = [i for i in positions if not 0 <= i < len(self.trained)]
        if bad:
            raise InputError(
                f"{self.record}: the run holds out view {bad[0]}, but the scene has {len(self.trained)} photos: "
                "not the scene the run was trained on"
            )
        names = {self.trained[i] for i in positions}
        return [i for i, f in enumerate(self.scene.frames) if f.name in names]

    def capture_index(self, q: float) -> float:
        """Index ``q`` on the dense scene's scale (a plan made on it) on the run's scale: linear between the two
        written frames it lies between (a planned pose lies on the segment between their poses), and past the
        ends along the end pair, as extrapolated poses are."""
        d = np.array([a for a, _ in self.anchors])
        c = np.array([b for _, b in self.anchors])
        if len(d) == 1:
            return float(q - d[0] + c[0])
        if q < d[0]:
            return float(c[0] + (q - d[0]) * (c[1] - c[0]) / (d[1] - d[0]))
        if q > d[-1]:
            return float(c[-1] + (q - d[-1]) * (c[-1] - c[-2]) / (d[-1] - d[-2]))
        return float(np.interp(q, d, c))

    def made_for_dense(self, names: Sequence[str] | None, n_views: int | None) -> bool:
        """Whether a plan recording these source views (names, else their number) was made on the dense scene
        as written rather than on the capture."""
        if names is not None:
            return sorted(map(str, names)) == sorted(f.name for f in self.dense.frames)
        return n_views == len(self.dense) and n_views != len(self.scene)


def read_record(path: Path) -> list[WrittenFrame]:
    """The frames of a ``sparself.json``; InputError naming it when it is unreadable or not sparself's."""
    try:
        doc = json.loads(path.read_text())
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise InputError(f"{path}: not a sparself scene record (expected format {FORMAT!r})")
        return [
            WrittenFrame(str(fr["name"]), bool(fr["synthetic"]), float(fr["index"]), str(fr["source_name"]))
            for fr in doc["frames"]
        ]
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({e})") from None
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"{path}: unreadable scene record ({type(e).__name__}: {e})") from None


def dense_photos(dense: Scene, folder: Path) -> DensePhotos | None:
    """The photos of ``dense`` (read from ``folder``) as the capture they came from; None when ``folder`` has
    no ``sparself.json`` (not a scene sparself wrote). InputError naming the record when it does not describe
    the scene (an image it does not list, a photo the scene lacks, two photos of one name)."""
    path = Path(folder) / SPARSELF_JSON
    if not path.is_file():
        return None
    record = read_record(path)
    by_name = {w.name: w for w in record}
    missing = [f.name for f in dense.frames if f.name not in by_name]
    if missing:
        raise InputError(
            f"{path}: does not list the scene's image {missing[0]!r} (the scene was changed after writing)"
        )
    have = {f.name for f in dense.frames}
    gone = [w.name for w in record if not w.synthetic and w.name not in have]
    if gone:
        raise InputError(f"{path}: lists the photo {gone[0]!r}, which the scene does not have")
    real = [f for f in dense.frames if not by_name[f.name].synthetic]
    if not real:
        raise InputError(f"{path}: the scene has no photos, only synthesized views")
    check_names([by_name[f.name].source_name for f in real], path, what="source_name", subfolders=True)
    source = {f.name: by_name[f.name].source_name for f in real}
    ordered = sorted(real, key=lambda f: capture_key(source[f.name]))
    frames = [replace(f, name=source[f.name], index=by_name[f.name].index) for f in ordered]
    scene = replace(
        dense,
        frames=frames,
        observations={source[n]: o for n, o in dense.observations.items() if n in source},
        frame_bounds={source[n]: b for n, b in dense.frame_bounds.items() if n in source},
    )
    trained = tuple(w.source_name for w in sorted((w for w in record if not w.synthetic), key=lambda w: w.index))
    anchors = tuple((float(f.index), by_name[f.name].index) for f in sorted(dense.frames, key=lambda f: f.index))
    return DensePhotos(scene, dense, trained, anchors, path)


def dense_scene_of_run(run_dir: Path) -> Path | None:
    """The dense scene ``densify`` wrote beside the run folder ``run_dir`` (``OUT/scene`` beside ``OUT/run``,
    its ``sparself.json`` naming that run); None when there is none."""
    run_dir = Path(run_dir)
    folder = run_dir.parent / SCENE_FOLDER
    try:
        named = json.loads((folder / SPARSELF_JSON).read_text()).get("run")
        return folder if named and (folder / named).resolve() == run_dir.resolve() else None
    except (OSError, ValueError, AttributeError, TypeError):
        return None
