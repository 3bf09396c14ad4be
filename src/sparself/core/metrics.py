"""Image quality metrics on (H, W, 3) float arrays in [0, 1]: PSNR, SSIM, LPIPS (only with real weights).

- :func:`psnr`: ``10 log10(max_val^2 / MSE)`` over all pixels and channels; identical images give
  ``float('inf')`` (the MSE is exactly zero, so there is no finite value to report).
- :func:`ssim`: the standard SSIM of Wang et al. 2004 with an 11x11 Gaussian window (sigma 1.5),
  K1 = 0.01, K2 = 0.03, population (not sample) covariances, computed per channel and averaged over the
  channels. It is kornia's ``kornia.metrics.ssim``, the one SSIM of the package (the training losses of the
  network and of 3DGS use its map too), here over the "valid" region (window positions fully inside the
  image) and without its eps, which is what ``skimage.metrics.structural_similarity(gaussian_weights=True,
  sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=-1)`` reports.
- :func:`lpips`: LPIPS v0.1 (AlexNet) of Zhang et al. 2018, implemented here in plain torch. It needs two
  weight files that cannot be downloaded here: torchvision's AlexNet ImageNet weights
  (``alexnet-owt-7be5be79.pth``) and LPIPS's linear layers (``alex.pth`` from the ``lpips`` package,
  ``lpips/weights/v0.1/alex.pth``). They are looked up in ``weights_dir`` / ``$SPARSELF_LPIPS_DIR``, the
  torch hub cache and an installed ``lpips`` package. Without both files the function returns None and
  :func:`lpips_status` says why; it never scores with a randomly initialised network.
"""

from __future__ import annotations

import logging
import math
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

_ALEXNET_FILE = "alexnet-owt-7be5be79.pth"
_LINEAR_FILE = "alex.pth"


def _pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if a.ndim not in (2, 3):
        raise ValueError(f"expected (H, W) or (H, W, C) images, got shape {a.shape}")
    return a, b


def psnr(a: np.ndarray, b: np.ndarray, max_val: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of two (H, W[, C]) images; ``inf`` for identical images."""
    a, b = _pair(a, b)
    mse = float(np.mean((a - b) ** 2))
    if mse == 0.0:
        return float("inf")
    return 10.0 * math.log10(max_val**2 / mse)


SSIM_WINDOW = 11  # px: the standard Gaussian window (sigma 1.5)


def ssim(a: np.ndarray, b: np.ndarray, data_range: float = 1.0) -> float:
    """Mean SSIM of two (H, W[, C]) images (each side >= 11 px): kornia's SSIM map in float64 over the
    valid region, without its stabilising eps, averaged over pixels and channels."""
    import torch
    from kornia.metrics import ssim as ssim_map

    a, b = _pair(a, b)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    if min(a.shape[:2]) < SSIM_WINDOW:
        raise ValueError(f"SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {a.shape[:2]}")

    def nchw(x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1)))[None]

    m = ssim_map(nchw(a), nchw(b), SSIM_WINDOW, max_val=float(data_range), eps=0.0, padding="valid")
    return float(m.mean())


def gain(after, before) -> np.ndarray:
    """Paired dB changes ``after - before`` (scores of the same photos, broadcast together); 0 where the two are
    equal, exact (inf) scores included, where ``inf - inf`` would be NaN.

    >>> gain([21.0, np.inf], [20.5, np.inf]).tolist()
    [0.5, 0.0]
    """
    a, b = np.asarray(after), np.asarray(before)
    out = np.zeros(np.broadcast_shapes(a.shape, b.shape), np.result_type(a, b, np.float64))
    return np.subtract(a, b, out=out, where=a != b)


def standard_error(values) -> float:
    """The standard error of the mean of ``values`` (any shape; sample standard deviation / sqrt(n)); NaN for fewer
    than two.

    >>> round(standard_error([1.0, 1.2, 0.8]), 4), standard_error([5.0])
    (0.1155, nan)
    """
    v = np.asarray(values, np.float64).ravel()
    return float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan")


def clear_gain(gain, floor: float = 0.0) -> bool:
    """Whether paired gains (one per photo, any shape) show a gain: their mean exceeds both ``floor`` and
    their standard error. One photo shows none (no spread to compare with).

    >>> clear_gain([1.0, 1.2, 0.8]), clear_gain([2.6, -0.6, -0.2]), clear_gain([5.0])
    (True, False, False)
    """
    g = np.asarray(gain, np.float64).ravel()
    if g.size < 2:
        return False
    return bool(g.mean() > max(floor, standard_error(g)))


def summarize(values) -> dict:
    """Mean, population std, min, max and count of finite values (``inf`` PSNRs are counted in n_inf).

    Returns dict(mean, std, min, max, n, n_inf); mean/std/min/max are NaN when there is no finite value.
    """
    v = np.asarray([float(x) for x in values if x is not None], dtype=np.float64)
    finite = v[np.isfinite(v)]
    nan = float("nan")
    if len(finite) == 0:
        return dict(mean=nan, std=nan, min=nan, max=nan, n=0, n_inf=int(np.isinf(v).sum()))
    return dict(
        mean=float(finite.mean()),
        std=float(finite.std()),
        min=float(finite.min()),
        max=float(finite.max()),
        n=int(len(finite)),
        n_inf=int(np.isinf(v).sum()),
    )


# ---- LPIPS -------------------------------------------------------------------------------------


def _candidate_dirs(weights_dir: str | os.PathLike | None) -> list[Path]:
    dirs: list[Path] = []
    if weights_dir is not None:
        dirs.append(Path(weights_dir))
    env = os.environ.get("SPARSELF_LPIPS_DIR")
    if env:
        dirs.append(Path(env))
    torch_home = Path(os.environ.get("TORCH_HOME", Path.home() / ".cache" / "torch"))
    dirs.append(torch_home / "hub" / "checkpoints")
    try:  # an installed lpips package ships its linear layers; find it without importing it
        import importlib.util

        spec = importlib.util.find_spec("lpips")
        if spec is not None and spec.origin:
            dirs.append(Path(spec.origin).parent / "weights" / "v0.1")
    except (ImportError, ValueError):
        pass
    return dirs


def _find_weights(weights_dir) -> tuple[Path | None, Path | None, list[Path]]:
    dirs = _candidate_dirs(weights_dir)
    alex = next((d / _ALEXNET_FILE for d in dirs if (d / _ALEXNET_FILE).is_file()), None)
    lin = next((d / _LINEAR_FILE for d in dirs if (d / _LINEAR_FILE).is_file()), None)
    return alex, lin, dirs


def lpips_status(weights_dir: str | os.PathLike | None = None) -> str:
    """'available: ...' naming the weight files used, or 'unavailable: ...' naming what is missing and where
    it was looked for."""
    alex, lin, dirs = _find_weights(weights_dir)
    if alex is not None and lin is not None:
        return f"available: LPIPS v0.1 AlexNet ({alex}, {lin})"
    missing = [n for n, p in ((_ALEXNET_FILE, alex), (_LINEAR_FILE, lin)) if p is None]
    return (
        f"unavailable: weights not found ({', '.join(missing)}) at any of "
        + ", ".join(str(d) for d in dirs)
        + "; set SPARSELF_LPIPS_DIR to a folder holding torchvision's AlexNet weights and lpips' v0.1 alex.pth"
    )


@lru_cache(maxsize=2)
def _lpips_net(alex_path: str, lin_path: str):
    import torch
    import torch.nn as nn

    class _LpipsAlex(nn.Module):
        """LPIPS v0.1 on AlexNet: torchvision's ``alexnet().features`` split after each ReLU."""

        chns = (64, 192, 384, 256, 256)

        def __init__(self) -> None:
            super().__init__()
            self.features = nn.Sequential(
                nn.Conv2d(3, 64, 11, 4, 2),
                nn.ReLU(),
                nn.MaxPool2d(3, 2),
                nn.Conv2d(64, 192, 5, padding=2),
                nn.ReLU(),
                nn.MaxPool2d(3, 2),
                nn.Conv2d(192, 384, 3, padding=1),
                nn.ReLU(),
                nn.Conv2d(384, 256, 3, padding=1),
                nn.ReLU(),
                nn.Conv2d(256, 256, 3, padding=1),
                nn.ReLU(),
            )
            self.taps = (1, 4, 7, 9, 11)  # outputs of relu1..relu5
            self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in self.chns)
            self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
            self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))

        def feats(self, x):
            x = (x - self.shift) / self.scale
            out = []
            for i, layer in enumerate(self.features):
                x = layer(x)
                if i in self.taps:
                    out.append(x / (torch.sqrt((x * x).sum(1, keepdim=True)) + 1e-10))
            return out

        def forward(self, a, b):
            fa, fb = self.feats(a), self.feats(b)
            return sum(lin((x - y) ** 2).mean((2, 3)) for lin, x, y in zip(self.lins, fa, fb))

    net = _LpipsAlex()
    alex_sd = torch.load(alex_path, map_location="cpu", weights_only=True)
    lin_sd = torch.load(lin_path, map_location="cpu", weights_only=True)
    sd = {k: v for k, v in alex_sd.items() if k.startswith("features.")}
    for i in range(5):
        sd[f"lins.{i}.weight"] = lin_sd[f"lin{i}.model.1.weight"]
    missing, unexpected = net.load_state_dict(sd, strict=False)
    missing = [m for m in missing if m not in ("shift", "scale")]
    if missing or unexpected:
        raise ValueError(f"LPIPS weights do not match the network: missing {missing}, unexpected {unexpected}")
    return net.eval()


_SAID: set[str] = set()  # LPIPS notices already logged


def lpips(a: np.ndarray, b: np.ndarray, weights_dir: str | os.PathLike | None = None) -> float | None:
    """LPIPS v0.1 (AlexNet) distance of two (H, W, 3) images in [0, 1]; None when the weights are not
    available locally (see :func:`lpips_status`). Lower is more similar."""
    a, b = _pair(a, b)
    alex, lin, _ = _find_weights(weights_dir)
    if alex is None or lin is None:
        status = lpips_status(weights_dir)
        if status not in _SAID:  # once per process, not once per scored image
            _SAID.add(status)
            log.info("LPIPS %s", status)
        return None
    import torch

    net = _lpips_net(str(alex), str(lin))

    def to_t(x):  # [0, 1] HWC -> [-1, 1] NCHW, as lpips(normalize=True) does
        return torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1)[None] * 2.0 - 1.0)).float()

    with torch.no_grad():
        return float(net(to_t(a), to_t(b)).item())
