"""3D reconstructors behind one call: ``fit(scene, **cfg) -> Renderer``; ``renderer.render(pose, camera)``.

``RECONSTRUCTORS`` maps a name to its ``fit``. Entries are imported only when used, so an optional
backend (gsplat needs CUDA) costs nothing until asked for. To add one, write ``sparself/recon/<name>.py``
with ``fit(scene, **cfg) -> Renderer`` and add ``"<name>": _lazy("<name>")`` below. "3dgs" picks gsplat
(CUDA) when it can run, else the CPU splatting of ``splat.py``.
"""

from __future__ import annotations

from typing import Callable, Protocol, runtime_checkable

import numpy as np

from sparself.capture.scene import Camera, Scene
from sparself.core.errors import ConfigError
from sparself.core.geometry import Pose


@runtime_checkable
class Renderer(Protocol):
    """A fitted reconstruction: renders any pose with any pinhole camera."""

    def render(self, pose: Pose, camera: Camera) -> np.ndarray:
        """-> (camera.height, camera.width, 3) float32 in [0, 1]."""
        ...


def _lazy(module: str, attr: str = "fit") -> Callable[..., Renderer]:
    """A ``fit`` that imports ``sparself.recon.<module>`` on first call."""

    def fit(scene: Scene, **cfg) -> Renderer:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{module}"), attr)(scene, **cfg)

    fit.__name__ = f"fit_{module}"
    fit.__doc__ = f"Lazily imported ``sparself.recon.{module}.{attr}(scene, **cfg)``."
    return fit


def backend(name: str) -> str:
    """The reconstructor that fits for ``name`` here: "3dgs" is gsplat on CUDA when it can run, else the
    plain-torch CPU path ("splat"); every other name is itself."""
    if name != "3dgs":
        return name
    from sparself.recon.gsplat import available

    return "gsplat" if available()[0] else "splat"


def fit_3dgs(scene: Scene, **cfg) -> Renderer:
    """3D Gaussian splatting on :func:`backend`'s choice. The renderer's ``backend`` says which ran."""
    return _lazy(backend("3dgs"))(scene, **cfg)


RECONSTRUCTORS: dict[str, Callable[..., Renderer]] = {
    "mpi": _lazy("mpi"),
    "nerf": _lazy("nerf"),
    "gsplat": _lazy("gsplat"),
    "splat": _lazy("splat"),
    "3dgs": fit_3dgs,
}


def get_reconstructor(name: str) -> Callable[..., Renderer]:
    """The ``fit`` registered under ``name``; ConfigError listing the known names otherwise."""
    try:
        return RECONSTRUCTORS[name]
    except KeyError:
        raise ConfigError(f"unknown reconstructor {name!r}; known: {', '.join(sorted(RECONSTRUCTORS))}") from None
