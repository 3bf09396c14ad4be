"""A stopped densify resumes: what it finished (SfM's poses, fits) is kept beside its output under a digest of
what it was made from, read back only for the same content, and the work folder is sparself's alone."""

from __future__ import annotations

import logging
import os
from dataclasses import replace

import numpy as np
import pytest

from planescene import small_plane_scene
from sparself import pipeline
from sparself.core.content import digest, keep, kept
from sparself.core.errors import OutputError
from sparself.core.outputs import MARKER, work_dir, work_path
from sparself.recon import pool
from sparself.recon.pool import Fitter
from test_bad_input import write_photos


def test_the_digest_follows_content_not_identity(tmp_path):
    scene = small_plane_scene(4)
    pixel = scene.frames[1].image.copy()
    pixel[3, 5, 0] += 1 / 255
    one_pixel = replace(scene, frames=[scene.frames[0], replace(scene.frames[1], image=pixel), *scene.frames[2:]])
    heavier = replace(scene, frames=[replace(f, weight=0.5) if i == 2 else f for i, f in enumerate(scene.frames)])
    copied = replace(scene, frames=[replace(f, image=f.image.copy()) for f in scene.frames])
    assert digest(scene) == digest(copied) == digest(small_plane_scene(4))
    assert len({digest(scene), digest(one_pixel), digest(heavier), digest(scene.subset([0, 1, 2]))}) == 4
    assert digest({"a": 1, "b": 2}) == digest({"b": 2, "a": 1}) != digest({"a": 1, "b": 3})
    assert digest(np.zeros(2, np.float32)) != digest(np.zeros(2, np.float64)) != digest(np.zeros((2, 1)))
    assert digest((1.0,)) != digest((1.0 + 2**-52,)) and digest([1]) != digest((1,))
    photo = tmp_path / "a.png"
    photo.write_bytes(b"x")
    first = digest(photo)
    os.utime(photo, ns=(1, 1))  # an edited photo is another input
    assert digest(photo) != first


def test_kept_values_come_back_equal_and_a_broken_file_is_a_miss(tmp_path):
    scene = small_plane_scene(3)
    assert keep(tmp_path / "s.pkl", scene) and digest(kept(tmp_path / "s.pkl")) == digest(scene)
    assert kept(tmp_path / "none.pkl") is None
    (tmp_path / "bad.pkl").write_bytes(b"not a pickle")
    assert kept(tmp_path / "bad.pkl") is None
    assert not keep(tmp_path / "f.pkl", lambda: 0) and not (tmp_path / "f.pkl").exists()  # cannot be pickled
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.pkl", "s.pkl"]  # no temporary file left


def test_fits_inside_a_work_folder_are_fitted_once_per_reconstructor_settings_and_scene(tmp_path, monkeypatch):
    fitted = []
    monkeypatch.setattr(pool, "_fitted", lambda fitters, scenes, within: [fitted.append(sc) or sc for sc in scenes])
    scene = small_plane_scene(5)
    a, b = scene.subset([0, 1, 2]), scene.subset([2, 3, 4])
    fitter = Fitter("3dgs", {"steps": 30, "seed": 0})
    with work_dir(tmp_path / "out", False) as work:
        assert [digest(r) for r in fitter.many([a, b])] == [digest(a), digest(b)]
        again = fitter.many([b, a, replace(a, bounds=(1.0, 5.0))])
        assert len(fitted) == 3 and digest(again[:2]) == digest([b, a])  # only the new scene was fitted
        fitter.with_seed(1).many([a])
        fitter.many([a], seeds=[2])
        Fitter("mpi")(a)
        Fitter("3dgs", {"steps": 30, "seed": 0, "progress": True}).many([a])  # a progress bar changes no fit
        assert len(fitted) == 6 and len(list((work / "fits").glob("*.pkl"))) == 6
    fitter.many([a])  # outside a work folder: nothing kept, everything fitted
    assert len(fitted) == 7


def test_sfm_poses_are_read_back_only_for_the_same_photos_and_options(tmp_path, monkeypatch):
    photos = tmp_path / "photos"
    paths = write_photos(photos, 4)
    work = tmp_path / "work"
    work.mkdir()
    calls = []

    def recovered(folder, cfg, beside=None):
        calls.append(folder)
        return small_plane_scene(4), None

    monkeypatch.setattr(pipeline, "recover_poses", recovered)
    cfg = pipeline.DensifyConfig()
    first = pipeline.read_input(photos, cfg, tmp_path / "out", work)
    again = pipeline.read_input(photos, cfg, tmp_path / "out", work)
    assert len(calls) == 1 and digest(again) == digest(first)
    pipeline.read_input(photos, replace(cfg, sfm=replace(cfg.sfm, matcher="sequential")), tmp_path / "out", work)
    assert len(calls) == 2  # other SfM options: recovered again
    pipeline.read_input(photos, cfg, tmp_path / "out", work)
    paths[2].write_bytes(paths[2].read_bytes() + b"\0")  # a photo changed since
    pipeline.read_input(photos, cfg, tmp_path / "out", work)
    assert len(calls) == 4
    pipeline.read_input(photos, cfg, tmp_path / "out", None)  # no work folder: nothing kept or read back
    assert len(calls) == 5


def test_the_work_folder_is_kept_only_after_a_stop_with_something_finished(tmp_path, caplog):
    out = tmp_path / "out"
    work = work_path(out)
    assert work == tmp_path / ".out.sparself-work"
    with work_dir(out, False, lambda w: True) as w:
        assert w == work and (w / MARKER).is_file()
    assert not work.exists()  # done: removed
    with pytest.raises(KeyboardInterrupt), work_dir(out, False, lambda w: False):
        raise KeyboardInterrupt
    assert not work.exists()  # stopped with nothing finished: removed
    with pytest.raises(RuntimeError), work_dir(out, False, lambda w: True) as w:
        (w / "step").write_text("done")
        raise RuntimeError
    assert (work / "step").is_file()  # stopped after a finished step: kept
    with caplog.at_level(logging.INFO), work_dir(out, True, lambda w: True) as w:
        assert (w / "step").is_file()  # resumed from it
    assert "resuming from" in caplog.text and not work.exists()
    with caplog.at_level(logging.INFO), work_dir(out, True, lambda w: True):
        pass
    assert "no stopped run to resume" in caplog.text


def test_a_run_without_resume_starts_anew_and_a_folder_not_ours_is_refused(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt), work_dir(out, False, lambda w: True) as w:
        (w / "step").write_text("done")
        raise KeyboardInterrupt
    with work_dir(out, False, lambda w: True) as w:
        assert not (w / "step").exists()
    mine = work_path(out)
    mine.mkdir()
    (mine / "notes.txt").write_text("a user's file")
    with pytest.raises(OutputError, match="sparself did not write it"), work_dir(out, True, lambda w: True):
        pass
    assert (mine / "notes.txt").read_text() == "a user's file"
