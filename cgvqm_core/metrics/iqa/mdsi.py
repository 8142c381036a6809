"""MDSI (Nafchi et al. 2016): mean deviation similarity index, lower is better.

Images on the 0..255 scale pooled by max(1, round(min(H, W) / 256)); LHM colour space;
Prewitt gradient similarity with the fused-average term (constants 140, 55) and chromaticity
similarity (550), combined by summation (alpha 0.6); deviation pooling with q = o = 0.25 and
rho = 1 (the real-valued path of the authors' complex power for the sum combination).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ._common import LHM, check_pair, colour_transform, gradient_magnitude, prewitt, similarity


def _complex_pow(base: torch.Tensor, exp: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Real and imaginary parts of base^exp for a real tensor (negative bases -> complex)."""
    r = base.abs() ** exp
    phi = torch.atan2(torch.zeros_like(base), base) * exp
    return r * torch.cos(phi), r * torch.sin(phi)


def mdsi(test: torch.Tensor, ref: torch.Tensor, *, c1: float = 140.0, c2: float = 55.0,
         c3: float = 550.0, alpha: float = 0.6, rho: float = 1.0, q: float = 0.25,
         o: float = 0.25) -> torch.Tensor:
    """MDSI of each image (lower is better, 0 = identical)."""
    check_pair(test, ref)
    if test.size(1) == 1:
        test, ref = test.repeat(1, 3, 1, 1), ref.repeat(1, 3, 1, 1)
    x, y = test * 255.0, ref * 255.0
    k = max(1, round(min(x.shape[-2:]) / 256))
    if k // 2:
        pads = [(k - 1) // 2, k // 2, (k - 1) // 2, k // 2]
        x, y = F.pad(x, pads), F.pad(y, pads)
    x, y = F.avg_pool2d(x, k), F.avg_pool2d(y, k)
    xl, yl = colour_transform(x, LHM), colour_transform(y, LHM)
    kern = prewitt(xl.dtype, xl.device)
    gx, gy = gradient_magnitude(xl[:, :1], kern), gradient_magnitude(yl[:, :1], kern)
    gavg = gradient_magnitude((xl[:, :1] + yl[:, :1]) / 2.0, kern)
    gs = similarity(gx, gy, c1) + similarity(gx, gavg, c2) - similarity(gy, gavg, c2)
    cs = (2 * (xl[:, 1:2] * yl[:, 1:2] + xl[:, 2:] * yl[:, 2:]) + c3) / (
        xl[:, 1:2] ** 2 + yl[:, 1:2] ** 2 + xl[:, 2:] ** 2 + yl[:, 2:] ** 2 + c3)
    gcs = alpha * gs + (1 - alpha) * cs
    re, im = _complex_pow(gcs, q)
    dev = ((re - re.mean(dim=(2, 3), keepdim=True)) ** 2
           + (im - im.mean(dim=(2, 3), keepdim=True)) ** 2).sqrt()
    return ((dev**rho).mean(dim=(-1, -2)) ** (o / rho)).squeeze(1)
