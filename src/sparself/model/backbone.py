"""ResNet-18 image encoder, defined here with torchvision's state-dict keys (classification head removed).

The ImageNet weights are torchvision's file ``resnet18-f37072fd.pth``, downloadable (with a network) from
``https://download.pytorch.org/models/resnet18-f37072fd.pth``. This project never downloads it: it loads
``--weights PATH`` if given, else the torch hub cache copy (``torch.hub.get_dir()/checkpoints/``) if present,
else it logs one warning and keeps the random initialisation.
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch
import torch.nn as nn

from sparself.core.errors import ConfigError, InputError

log = logging.getLogger(__name__)

RESNET18_URL = "https://download.pytorch.org/models/resnet18-f37072fd.pth"
RESNET18_FILE = "resnet18-f37072fd.pth"


class BasicBlock(nn.Module):
    """Two 3x3 conv-BN layers with a skip connection: F(x) = relu(x + conv(x)) (torchvision's layout)."""

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.downsample = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        idt = x if self.downsample is None else self.downsample(x)
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        return self.relu(y + idt)


class ResNet18(nn.Module):
    """ResNet-18 without its classification layer: (B, 3, H, W) ImageNet-normalised -> (B, 512).

    State-dict keys equal torchvision's ``resnet18()`` minus ``fc.weight``/``fc.bias``.

    Batch normalisation always uses its running statistics (frozen BN, as in detection fine-tuning; its
    affine parameters still train): a frame's features then never depend on the other frames of a batch,
    so a leave-one-out target cannot leak into its sources through batch statistics.
    """

    def __init__(self) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(3, 64, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        self.layer1 = nn.Sequential(BasicBlock(64, 64), BasicBlock(64, 64))
        self.layer2 = nn.Sequential(BasicBlock(64, 128, 2), BasicBlock(128, 128))
        self.layer3 = nn.Sequential(BasicBlock(128, 256, 2), BasicBlock(256, 256))
        self.layer4 = nn.Sequential(BasicBlock(256, 512, 2), BasicBlock(512, 512))
        self.avgpool = nn.AdaptiveAvgPool2d(1)
        for m in self.modules():  # torchvision's initialisation
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        # Zero-init the last BN of each block (torchvision's zero_init_residual option): with frozen BN
        # and random weights, blocks start as identities so activations stay bounded.
        for m in self.modules():
            if isinstance(m, BasicBlock):
                nn.init.zeros_(m.bn2.weight)

    def train(self, mode: bool = True) -> "ResNet18":
        super().train(mode)
        for m in self.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.eval()
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, 3, H, W) -> (B, 512) globally average-pooled features."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        x = self.layer4(self.layer3(self.layer2(self.layer1(x))))
        return torch.flatten(self.avgpool(x), 1)


IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


NO_WEIGHTS = "none"  # --weights none: random initialisation, no warning


def hub_weights_path() -> Path:
    """Where torch hub caches torchvision's ResNet-18 file."""
    return Path(torch.hub.get_dir()) / "checkpoints" / RESNET18_FILE


def default_weights() -> str:
    """The weights used when none are given: the torch hub cache file if present, else ``"none"``
    (random initialisation) after a note that says where to put the file (not a warning: it is the usual case
    on a machine without a network, so -q keeps quiet about it; config.json records the weights used)."""
    cached = hub_weights_path()
    if cached.is_file():
        return str(cached)
    log.info(
        "no ImageNet weights for ResNet-18 (no --weights and no %s); using random initialisation. "
        "Download %s there to use them.",
        cached,
        RESNET18_URL,
    )
    return NO_WEIGHTS


_WEIGHTS_HINT = "give torchvision's resnet18-f37072fd.pth, or --weights none"


def _check_weights_file(path: Path) -> None:
    """A file torch.save wrote starts as a zip archive or a pickle; anything else gets a plain message."""
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    if not head:
        raise InputError(f"{path}: weights file is empty (0 bytes); {_WEIGHTS_HINT}")
    if not (head.startswith(b"PK") or head[:1] == b"\x80"):
        raise InputError(
            f"{path}: cannot read as torch weights: not a zip archive or a pickle (what torch.save "
            f"writes); {_WEIGHTS_HINT}"
        )


def load_resnet18_weights(model: ResNet18, path: Path | str | None = None) -> str:
    """Load ImageNet weights into ``model`` strictly; returns where they came from ("random" if none).

    path: a torchvision-layout checkpoint (a state dict, optionally with ``fc.*`` which is dropped);
    ``"none"``: keep the random initialisation without a warning (the caller has already said so).
    Without path: :func:`default_weights` (the torch hub cache file, else one warning and random
    initialisation; download ``RESNET18_URL`` into ``hub_weights_path()`` on a machine with a network).
    Raises InputError if the file is missing or unreadable, ConfigError if its keys or shapes differ.
    """
    if path is None:
        path = default_weights()
    elif str(path) == NO_WEIGHTS:
        log.info("ResNet-18: random initialisation (--weights none)")
    if str(path) == NO_WEIGHTS:
        return "random"
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: weights file not found")
    _check_weights_file(path)
    try:
        sd = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # pickle/zip errors come in many types; torch's text adds pages of advice
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise InputError(f"{path}: cannot read as torch weights ({first}); {_WEIGHTS_HINT}") from None
    if isinstance(sd, dict) and "state_dict" in sd and isinstance(sd["state_dict"], dict):
        sd = sd["state_dict"]
    if not isinstance(sd, dict) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise ConfigError(f"{path}: not a state dict of tensors (expected torchvision's resnet18 layout)")
    sd = {k: v for k, v in sd.items() if not k.startswith("fc.")}
    own = model.state_dict()
    missing = sorted(set(own) - set(sd))
    unexpected = sorted(set(sd) - set(own))
    if missing or unexpected:
        raise ConfigError(
            f"{path}: not a torchvision ResNet-18 checkpoint: {len(missing)} missing keys "
            f"(e.g. {missing[:3]}), {len(unexpected)} unexpected keys (e.g. {unexpected[:3]})"
        )
    bad = [k for k in own if own[k].shape != sd[k].shape]
    if bad:
        raise ConfigError(
            f"{path}: shape mismatch for {bad[:3]} (e.g. {tuple(sd[bad[0]].shape)} vs "
            f"{tuple(own[bad[0]].shape)}); is this ResNet-18?"
        )
    model.load_state_dict(sd, strict=True)
    log.info("loaded ResNet-18 weights from %s", path)
    return str(path)
