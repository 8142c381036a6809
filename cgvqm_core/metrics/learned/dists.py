"""DISTS (Ding et al. 2020) as PIQ 0.8 defines it.

VGG-16 whose max-pooling is replaced by L2 pooling (a 3x3 Hann window, stride 2, on the
squared activations); frames whose shorter side exceeds 256 pixels are first resized
bilinearly so that it becomes 256 (PIQ's ``F.interpolate`` with ``scale_factor``). For the
input itself and the five ReLU outputs relu1_2 ... relu5_3, per channel: a structure term
from the spatial means, (2 mx my + c) / (mx^2 + my^2 + c), and a texture term from the
(co)variances, (2 cxy + c) / (vx + vy + c), c = 1e-6; the learned alpha and beta weight
them; DISTS = 1 - sum(alpha * S + beta * T). The published alpha and beta sum to 1, so
identical images give 0 (the authors' code divides by that sum; PIQ uses them as stored).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..iqa._common import check_pair
from .lpips import IMAGENET_MEAN, IMAGENET_STD
from .vgg import TAPS, tapped

CHANNELS = (3, 64, 128, 256, 512, 512)  # the input, then relu1_2 ... relu5_3
C = 1e-6
RESIZE_TO = 256


class L2Pool(nn.Module):
    """sqrt(Hann-3x3 * x^2 + 1e-12), stride 2, padding 1, per channel (DISTS's L2 pooling)."""

    EPS = 1e-12

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        w = torch.hann_window(5, periodic=False, dtype=x.dtype, device=x.device)[1:-1]
        k = w[:, None] * w[None, :]
        k = (k / k.sum()).expand(x.shape[1], 1, 3, 3)
        out = F.conv2d(x ** 2, k, stride=2, padding=1, groups=x.shape[1])
        return (out + self.EPS).sqrt()


class DISTS(nn.Module):
    """DISTS over VGG-16 ``features`` built with :class:`L2Pool` pooling."""

    def __init__(self, features: nn.Sequential, alpha: torch.Tensor, beta: torch.Tensor
                 ) -> None:
        super().__init__()
        if any(isinstance(m, nn.MaxPool2d) for m in features):
            raise ValueError("DISTS needs VGG-16 features built with L2 pooling")
        self.features = features
        self.register_buffer("alpha", alpha.detach().reshape(1, -1, 1, 1).float())
        self.register_buffer("beta", beta.detach().reshape(1, -1, 1, 1).float())
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1))

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """(N,) DISTS of x and y, (N, 3, H, W) RGB in [0, 1]."""
        check_pair(x, y, channels=(3,))
        h, w = x.shape[-2:]
        if min(h, w) > RESIZE_TO:
            scale = RESIZE_TO / min(h, w)
            x = F.interpolate(x, scale_factor=scale, recompute_scale_factor=False,
                              mode="bilinear")
            y = F.interpolate(y, scale_factor=scale, recompute_scale_factor=False,
                              mode="bilinear")
        n = x.shape[0]
        z = torch.cat([x, y])
        feats = [z, *tapped(self.features, (z - self.mean) / self.std, TAPS)]
        alphas = torch.split(self.alpha, CHANNELS, dim=1)
        betas = torch.split(self.beta, CHANNELS, dim=1)
        total = x.new_zeros(n)
        for f, a, b in zip(feats, alphas, betas, strict=True):
            fx, fy = f[:n], f[n:]
            mx = fx.mean(dim=(2, 3), keepdim=True)
            my = fy.mean(dim=(2, 3), keepdim=True)
            structure = (2 * mx * my + C) / (mx ** 2 + my ** 2 + C)
            vx = ((fx - mx) ** 2).mean(dim=(2, 3), keepdim=True)
            vy = ((fy - my) ** 2).mean(dim=(2, 3), keepdim=True)
            cxy = (fx * fy).mean(dim=(2, 3), keepdim=True) - mx * my
            texture = (2 * cxy + C) / (vx + vy + C)
            total = total + (structure * a).sum(dim=(1, 2, 3)) + (texture * b).sum(dim=(1, 2, 3))
        return 1 - total
