"""LPIPS (Zhang et al. 2018) as PIQ 0.8 defines it, on any torchvision-layout feature network.

Per frame pair: both images normalised with ImageNet's mean and std (for inputs in [0, 1]
this is exactly LPIPS's scaling layer, whose shift and scale are 2*mean-1 and 2*std for
inputs in [-1, 1]); the ReLU outputs at five depths, each unit-normalised over channels
(x / (||x|| + 1e-10)); the squared difference weighted per channel by the learned linear
head (LPIPS's 1x1 convolution without bias), averaged over space and summed over channels
and depths. 0 for identical images; symmetric in its two arguments.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ..iqa._common import check_pair
from .vgg import tapped

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
EPS = 1e-10  # added to the feature norm (PIQ and the LPIPS package)
STRIPE_PIXELS = 1 << 16  # pixels per image in one band of :func:`tap_distance`


def unit_normalise(f: torch.Tensor) -> torch.Tensor:
    return f / (torch.sqrt(torch.sum(f ** 2, dim=1, keepdim=True)) + EPS)


class LPIPS(nn.Module):
    """LPIPS over ``features`` (a torchvision ``features`` Sequential) at ``taps``."""

    def __init__(self, features: nn.Sequential, taps: Sequence[int],
                 heads: Sequence[torch.Tensor]) -> None:
        super().__init__()
        if len(heads) != len(taps):
            raise ValueError(f"{len(taps)} taps need as many heads, got {len(heads)}")
        self.features = features
        self.taps = tuple(taps)
        for k, h in enumerate(heads):
            self.register_buffer(f"head{k}", h.detach().reshape(1, -1, 1, 1).float())
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1))

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """(N,) distances of x and y, (N, 3, H, W) RGB in [0, 1]."""
        check_pair(x, y, channels=(3,))
        n = x.shape[0]
        z = (torch.cat([x, y]) - self.mean) / self.std  # one pass for both images
        total = x.new_zeros(n, dtype=torch.float64)
        for k, f in enumerate(tapped(self.features, z, self.taps)):
            total += tap_distance(f, n, getattr(self, f"head{k}"))
        return total


def tap_distance(f: torch.Tensor, n: int, head: torch.Tensor) -> torch.Tensor:
    """(N,) float64 spatial mean of the head-weighted squared difference of the unit-
    normalised features f[:n] and f[n:], a band of rows at a time (the temporaries of a
    whole 1080p frame's first layers would be gigabytes)."""
    h, w = f.shape[-2:]
    rows = max(1, STRIPE_PIXELS // max(1, w))
    total = f.new_zeros(n, dtype=torch.float64)
    for r0 in range(0, h, rows):
        s = unit_normalise(f[..., r0:r0 + rows, :])
        d = (s[:n] - s[n:]) ** 2
        total += (d * head).sum(dim=(1, 2, 3), dtype=torch.float64)
    return total / (h * w)
