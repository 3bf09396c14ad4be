"""`sparself info`: what a scene holds — views, image size, cameras, field of view, pose bounds."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from sparself.capture.scene import Scene
from sparself.core.geometry import path_steps

# the names sparself gives synthesized views (sparself.synthesis.plan_files.novel_name, maybe behind a rank prefix)
_NOVEL = re.compile(r"(^|_)novel_-?\d+\.\d\d\.png$")


def synthesized_views(scene: Scene) -> list[str]:
    """Names of the views sparself synthesized: flagged by the reader (sparself.json), or, in a scene
    without that record, named like them."""
    return [f.name for f in scene.frames if f.synthetic or _NOVEL.search(Path(f.name).name)]


def depth_bounds_origin(scene: Scene) -> str:
    """Where :meth:`Scene.depth_bounds` takes near/far from, in words (the same tests, in the same order)."""
    if scene.bounds is not None:
        name = Path(scene.source).name if scene.source is not None else "the scene"
        return f"the near/far bounds stored in {name}"
    if scene.points is not None and len(scene.points) >= 10:
        n = sum(int(np.sum((scene.points @ f.pose.R.T + f.pose.tvec)[:, 2] > 0)) for f in scene.frames)
        if n >= 10:
            return (
                f"depths of the {len(scene.points)} sparse points in front of the cameras "
                "(1st and 99th percentile, widened by 10%)"
            )
    return (
        "a guess from the camera layout (0.2x and 5x the cameras' median distance to their centroid): "
        "the scene has no stored bounds and too few sparse points"
    )


def scene_info(scene: Scene) -> dict:
    """A JSON-ready summary of a scene (no image is decoded).

    Keys: views (real_views + synthesized_views), sizes, cameras (model, size, fx, fy, cx, cy, params,
    fov_deg, and undistorted_from: the files' lens model where its photos are read undistorted),
    centers (min, max, extent), scale, depth_bounds + depth_bounds_from,
    step (median distance and rotation between consecutive views).
    """
    cams = {}
    for cid, c in sorted(scene.cameras.items()):
        fh, fv = c.fov_deg
        cams[str(cid)] = {
            "model": c.model,
            "width": c.width,
            "height": c.height,
            "fx": c.fx,
            "fy": c.fy,
            "cx": c.cx,
            "cy": c.cy,
            "params": list(c.params),
            "fov_deg": [round(fh, 4), round(fv, 4)],
            "views": sum(1 for f in scene.frames if f.camera_id == cid),
        }
        if cid in scene.undistort:  # the files' camera, whose photos every command reads undistorted
            lens = scene.undistort[cid].lens
            cams[str(cid)]["undistorted_from"] = {"model": lens.model, "params": list(lens.params)}
    centers = scene.centers()
    src = depth_bounds_origin(scene)
    synth = synthesized_views(scene)
    near, far = scene.depth_bounds() if len(scene) else (float("nan"), float("nan"))
    steps_d, steps_r = path_steps([f.pose for f in scene.frames])
    return {
        "source": str(scene.source) if scene.source is not None else None,
        "views": len(scene),
        "real_views": len(scene) - len(synth),
        "synthesized_views": len(synth),
        "sizes": sorted(
            {f"{scene.cameras[f.camera_id].width}x{scene.cameras[f.camera_id].height}" for f in scene.frames}
        ),
        "cameras": cams,
        "centers": {
            "min": centers.min(0).tolist() if len(scene) else None,
            "max": centers.max(0).tolist() if len(scene) else None,
            "extent": (centers.max(0) - centers.min(0)).tolist() if len(scene) else None,
        },
        "scale": scene.scale() if len(scene) else None,
        "depth_bounds": [near, far],
        "depth_bounds_from": src,
        "step": {
            "median_distance": float(np.median(steps_d)) if len(steps_d) else None,
            "median_rotation_deg": float(np.median(steps_r)) if len(steps_r) else None,
        },
        "points": int(len(scene.points)) if scene.points is not None else 0,
    }


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"


def format_info(info: dict) -> str:
    """Human-readable text of :func:`scene_info`'s dict."""
    lines = [
        f"scene:         {info['source'] or '(in memory)'}",
        f"views:         {info['views']} ({info.get('real_views', info['views'])} real + "
        f"{info.get('synthesized_views', 0)} synthesized)",
        f"image size:    {', '.join(info['sizes'])} (W x H)",
    ]
    lines += _camera_lines(info["cameras"])
    lines += _layout_lines(info)
    return "\n".join(lines)


SUMMARY_OVER = 4  # more cameras than this (phones vary the focal length: one per photo) are summarised


def _camera_lines(cams: dict) -> list[str]:
    """One block per camera, or past SUMMARY_OVER one line with the ranges (the full list is in --json)."""
    if len(cams) > SUMMARY_OVER:
        cs = list(cams.values())

        def span(get, fmt: str = ".0f") -> str:
            lo, hi = f"{min(map(get, cs)):{fmt}}", f"{max(map(get, cs)):{fmt}}"
            return lo if lo == hi else f"{lo}–{hi}"

        models = ", ".join(sorted({c["model"] for c in cs}))
        return [
            f"cameras:       {len(cs)} cameras ({models}), fx {span(lambda c: c['fx'])} px, "
            f"fy {span(lambda c: c['fy'])} px (--json lists each)",
            f"  field of view: {span(lambda c: c['fov_deg'][0], '.1f')} x {span(lambda c: c['fov_deg'][1], '.1f')} deg "
            "(horizontal x vertical)",
        ]
    lines = []
    for cid, c in cams.items():
        lines.append(
            f"camera {cid}:      {c['model']} {c['width']}x{c['height']}, "
            f"fx={c['fx']:.2f} fy={c['fy']:.2f} cx={c['cx']:.2f} cy={c['cy']:.2f} ({c['views']} views)"
        )
        lines.append(f"  field of view: {c['fov_deg'][0]:.2f} x {c['fov_deg'][1]:.2f} deg (horizontal x vertical)")
        if "undistorted_from" in c:
            lens = c["undistorted_from"]
            lines.append(
                f"  lens:          {lens['model']} ({', '.join(f'{p:.4g}' for p in lens['params'])}); "
                "its photos are read undistorted, as this pinhole camera"
            )
    return lines


def _layout_lines(info: dict) -> list[str]:
    lines = []
    if info["views"]:
        cen = info["centers"]
        lines.append(f"camera centres: min {_vec(cen['min'])}  max {_vec(cen['max'])}  extent {_vec(cen['extent'])}")
        lines.append(f"scene scale:   {info['scale']:.4g} (median distance of camera centres to their mean)")
        near, far = info["depth_bounds"]
        lines.append(f"depth bounds:  near {near:.4g}, far {far:.4g}, from {info['depth_bounds_from']}")
    st = info["step"]
    if st["median_distance"] is not None:
        lines.append(
            f"median step:   {st['median_distance']:.4g} between consecutive views, "
            f"{st['median_rotation_deg']:.2f} deg rotation"
        )
    if info["points"]:
        lines.append(f"sparse points: {info['points']}")
    return lines


def describe(scene_path: Path, as_json: bool = False) -> str:
    """Read a scene (anything :func:`sparself.capture.io.read_scene` accepts) and describe it as text or JSON."""
    from sparself.capture.io import read_scene

    info = scene_info(read_scene(Path(scene_path)))
    return json.dumps(info, indent=1) if as_json else format_info(info)
