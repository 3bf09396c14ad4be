"""COLMAP sees the photos under aliases that sort in capture order, so that ``--matcher sequential`` pairs
neighbours in capture order (``IMG_2`` with ``IMG_3``, not with ``IMG_10``), and every name it returns is
mapped back: nothing after SfM sees an alias."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image

from sparself.capture.images import load_image
from sparself.capture.sfm import SfmConfig, recover_poses
from sparself.capture.sfm_images import WorkImages, alias_names, work_images
from sparself.core.geometry import Pose, rotmat_to_quat
from sparself.core.interrupts import import_native
from sparself.core.names import capture_key
from test_bad_input import render_corner

NAMES = [f"IMG_{k}.png" for k in range(1, 13)]  # no zero padding: text order is IMG_1, IMG_10, IMG_11, IMG_12, IMG_2


def test_aliases_sort_as_text_in_capture_order():
    names = ["b_10.JPG", "B_9.jpg", "a.png", "img_100.png", "img_2.png", "img_11.png"] + NAMES
    alias = alias_names(names[::-1])
    assert sorted(alias, key=capture_key) == sorted(names, key=lambda n: alias[n])  # text order of the aliases
    assert len(set(alias.values())) == len(names)
    assert all(os.path.splitext(a)[1] == os.path.splitext(n)[1] for n, a in alias.items())
    assert sorted(NAMES) != sorted(NAMES, key=capture_key)  # the case the aliases are for


def _look_at(c: np.ndarray, target: np.ndarray) -> Pose:
    z = (target - c) / np.linalg.norm(target - c)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return Pose(rotmat_to_quat(R), -R @ c)


def _photos(folder, names=NAMES, gray: str = ""):
    """Views of a textured box corner along an arc, in the capture order of ``names``; ``gray`` saved as 8-bit gray."""
    folder.mkdir()
    for i, name in enumerate(sorted(names, key=capture_key)):
        a = -0.3 + 0.6 * i / (len(names) - 1)
        c = np.array([np.sin(a) - 0.3, 0.2 * np.cos(3 * a), -2 + 0.3 * np.cos(a)])
        im = Image.fromarray(
            (np.clip(render_corner(_look_at(c, np.array([-0.3, 0.3, 1.5]))), 0, 1) * 255).astype(np.uint8)
        )
        (im.convert("L") if name == gray else im).save(folder / name)
    return folder


def test_work_folder_links_photos_under_their_aliases_and_converts_odd_ones(tmp_path):
    d = _photos(tmp_path / "photos", NAMES[:4], gray="IMG_2.png")
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    work = tmp_path / "work"
    work.mkdir()
    images = work_images(sorted(d.iterdir(), key=lambda p: capture_key(p.name)), work)
    assert list(images.aliases) == sorted(images.aliases) == sorted(p.name for p in images.folder.iterdir())
    assert [images.user[a] for a in images.aliases] == sorted(NAMES[:4], key=capture_key)
    for a in images.aliases:
        p, src = images.folder / a, d / images.user[a]
        assert p.is_symlink() != (images.user[a] == "IMG_2.png")  # the gray photo: an upright RGB copy
        np.testing.assert_array_equal(load_image(p), load_image(src))
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before


def test_reconstructions_are_renamed_to_the_users_names():
    pycolmap = import_native("pycolmap")
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera(model="PINHOLE", width=8, height=8, params=[4, 4, 4, 4], camera_id=1)
    )
    alias = alias_names(NAMES)
    for k, n in enumerate(NAMES):
        img = pycolmap.Image(name=alias[n], camera_id=1, image_id=k + 1)
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d())
    images = WorkImages(Path("."), tuple(sorted(alias.values())), {a: n for n, a in alias.items()})
    assert images.to_user_names(rec) is rec
    assert {i: im.name for i, im in rec.images.items()} == {k + 1: n for k, n in enumerate(NAMES)}


def test_sequential_matching_pairs_neighbours_in_capture_order(tmp_path, monkeypatch):
    """One real SfM run (a few seconds) on photos named IMG_1 .. IMG_12: every pair COLMAP matched is two
    photos at most ``overlap`` apart in capture order, every capture-order neighbour pair is matched, and the
    scene and report name the photos as the user does."""
    pycolmap = import_native("pycolmap")
    d = _photos(tmp_path / "photos")
    real, pairs = pycolmap.match_sequential, []

    def spy(db, **kw):
        real(db, **kw)
        base = pycolmap.Database.open(db)
        try:
            names = {im.image_id: im.name for im in base.read_all_images()}
            for pid in base.read_all_matches()[0]:
                a, b = pycolmap.pair_id_to_image_pair(pid)
                pairs.append((names[a], names[b]))
        finally:
            base.close()

    monkeypatch.setattr(pycolmap, "match_sequential", spy)
    scene, report = recover_poses(d, SfmConfig(matcher="sequential", sequential_overlap=2))
    capture = sorted(NAMES, key=capture_key)
    rank = {a: capture.index(n) for n, a in alias_names(NAMES).items()}  # COLMAP's name -> rank in capture order
    steps = sorted({abs(rank[a] - rank[b]) for a, b in pairs})
    assert pairs and max(steps) <= 2
    assert {tuple(sorted((rank[a], rank[b]))) for a, b in pairs} >= {(k, k + 1) for k in range(len(NAMES) - 1)}
    assert report.num_registered >= 10 and set(report.registered) <= set(NAMES)
    assert [f.name for f in scene.frames] == sorted(report.registered, key=capture_key)
    assert all(f.path == d / f.name for f in scene.frames)
