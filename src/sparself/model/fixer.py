"""The fixer: a synthesized view and a reconstruction's render at the same pose, merged pixel by pixel.

A reconstruction fitted on the photos renders some regions better than the network (it has seen them from
many photos) and others worse (floaters, holes, blur where photos are few); the network's view fails
elsewhere (occlusions, depth ambiguity). The fixer is a small CNN that predicts, per pixel, how much of
the view to keep: ``fixed = g * view + (1 - g) * render``. It reads the two images, their difference and the
network's confidence, and is trained on input photos that neither the render nor the view saw (the
reconstruction fitted without them, the views synthesized without them), so what it learns is where each
of the two is right on this capture.

The gate runs at the render's (low) resolution; at a higher output size only the low frequencies of the
view are corrected (:func:`fix_views`), so the view's detail survives a coarse render.
"""

from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

IN_CHANNELS = 8  # view (3), render (3), their mean absolute difference (1), the view's confidence (1)


class Fixer(nn.Module):
    """Per-pixel gate between a view and a render: (B, 3, h, w) x 2 + (B, 1, h, w) -> (B, 1, h, w) in [0, 1]."""

    def __init__(self, hidden: int = 8) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(IN_CHANNELS, hidden, 3, padding=1, padding_mode="replicate"),
            nn.ReLU(),
            nn.Conv2d(hidden, hidden, 3, padding=1, padding_mode="replicate"),
            nn.ReLU(),
            nn.Conv2d(hidden, 1, 1),
        )

    def logits(self, view: torch.Tensor, render: torch.Tensor, confidence: torch.Tensor) -> torch.Tensor:
        """The gate before its sigmoid: (B, 1, h, w)."""
        diff = (view - render).abs().mean(1, keepdim=True)
        return self.net(torch.cat([view, render, diff, confidence], 1))

    def forward(self, view: torch.Tensor, render: torch.Tensor, confidence: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.logits(view, render, confidence))


def best_gate(view: torch.Tensor, render: torch.Tensor, truth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The per-pixel gate g* in [0, 1] whose blend is nearest ``truth`` (least squares over the colour
    channels) and the weight of that pixel, ``|view - render|^2`` (a pixel where the two agree does not care
    about its gate). All (B, 3, h, w) -> two (B, 1, h, w)."""
    d, e = view - render, truth - render
    dd = (d * d).sum(1, keepdim=True)
    return ((d * e).sum(1, keepdim=True) / dd.clamp_min(1e-8)).clamp(0.0, 1.0), dd


def blend(fixer: Fixer, view: torch.Tensor, render: torch.Tensor, confidence: torch.Tensor) -> torch.Tensor:
    """The fixed views at the render's size: g * view + (1 - g) * render. All (B, C, h, w) -> (B, 3, h, w)."""
    g = fixer(view, render, confidence)
    return g * view + (1.0 - g) * render


def fix_views(fixer: Fixer, view: torch.Tensor, render: torch.Tensor, confidence: torch.Tensor) -> torch.Tensor:
    """Fixed views at the view's size.

    view: (B, 3, H, W); render: (B, 3, h, w) with h <= H, w <= W; confidence: (B, 1, H, W) or (B, 1, h, w).
    The gate is computed at (h, w) on the area-averaged view; its correction ``(1 - g) (render - view)`` is
    upsampled and added to the full-size view, so at (h, w) this equals :func:`blend`. Returns (B, 3, H, W)
    in [0, 1]."""
    hw = render.shape[-2:]
    small = F.interpolate(view, size=hw, mode="area") if view.shape[-2:] != hw else view
    conf = F.interpolate(confidence, size=hw, mode="area") if confidence.shape[-2:] != hw else confidence
    g = fixer(small, render, conf)
    corr = (1.0 - g) * (render - small)
    if corr.shape[-2:] != view.shape[-2:]:
        corr = F.interpolate(corr, size=view.shape[-2:], mode="bilinear", align_corners=False)
    return (view + corr).clamp(0.0, 1.0)


def train_fixer(
    view: torch.Tensor,
    render: torch.Tensor,
    confidence: torch.Tensor,
    truth: torch.Tensor,
    steps: int = 300,
    lr: float = 1e-2,
    seed: int = 0,
) -> Fixer:
    """A fixer fitted so that :func:`blend` matches ``truth``, all (B, C, h, w) at one size.

    The squared error of a blend is ``|view - render|^2 (g - g*)^2`` plus a constant (:func:`best_gate`), so
    the gate is fitted to g* by cross-entropy on its logits with that weight: the same optimum, but the
    gradient does not vanish when the sigmoid saturates (a loss on the blend itself drives every gate to the
    image that is right more often and stays there). The gate starts at 1/2 (the plain average); with a
    handful of training photos the network is kept small (about 1,300 weights) so that it learns where to
    trust each image, not the photos themselves."""
    gen = torch.Generator().manual_seed(seed)
    fixer = Fixer()
    with torch.no_grad():
        for p in fixer.parameters():
            p.copy_(torch.randn(p.shape, generator=gen) * (0.1 if p.dim() > 1 else 0.0))
    opt = torch.optim.Adam(fixer.parameters(), lr=lr)
    target, weight = best_gate(view, render, truth)
    total = weight.sum().clamp_min(1e-8)
    for _ in range(steps):
        opt.zero_grad()
        each = F.binary_cross_entropy_with_logits(fixer.logits(view, render, confidence), target, reduction="none")
        loss = (each * weight).sum() / total
        loss.backward()
        opt.step()
    return fixer.eval()
