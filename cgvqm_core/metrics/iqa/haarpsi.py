"""HaarPSI (Reisenhofer et al. 2018): Haar wavelet-based perceptual similarity, on YIQ.

Images on the 0..255 scale halved by 2x2 average pooling; three Haar scales on luma (weights
from the coarsest), I/Q compared after 2x2 averaging; constant 30, logistic slope 4.2.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ._common import YIQ, check_pair, colour_transform, halve, similarity


def _haar(n: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    k = torch.ones(n, n, dtype=dtype, device=device) / n
    k[n // 2:] = -k[n // 2:]
    return k


def haarpsi(test: torch.Tensor, ref: torch.Tensor, *, scales: int = 3, subsample: bool = True,
            c: float = 30.0, alpha: float = 4.2) -> torch.Tensor:
    """HaarPSI of each image (higher is better, 1 = identical)."""
    check_pair(test, ref)
    if min(test.shape[-2:]) < 2 ** (scales + 1):
        raise ValueError(f"HaarPSI needs at least {2 ** (scales + 1)} pixels")
    x, y = test * 255.0, ref * 255.0
    rgb = x.size(1) == 3
    if rgb:
        x, y = colour_transform(x, YIQ), colour_transform(y, YIQ)
    if subsample:
        x, y = halve(x), halve(y)
    cx, cy = [], []
    for s in range(scales):
        n = 2 ** (s + 1)
        h = _haar(n, x.dtype, x.device)
        kern = torch.stack([h, h.t()])[:, None]
        pads = [n // 2 - 1, n // 2, n // 2 - 1, n // 2]
        cx.append(F.conv2d(F.pad(x[:, :1], pads), kern))
        cy.append(F.conv2d(F.pad(y[:, :1], pads), kern))
    ax, ay = torch.cat(cx, 1), torch.cat(cy, 1)  # (B, 2 * scales, H, W)
    weights = torch.maximum(ax[:, 4:].abs(), ay[:, 4:].abs())
    maps = []
    for o in range(2):
        maps.append(similarity(ax[:, (o, o + 2)].abs(), ay[:, (o, o + 2)].abs(), c)
                    .sum(1, keepdim=True) / 2)
    if rgb:
        iq_x = F.avg_pool2d(F.pad(x[:, 1:], [0, 1, 0, 1]), 2, stride=1).abs()
        iq_y = F.avg_pool2d(F.pad(y[:, 1:], [0, 1, 0, 1]), 2, stride=1).abs()
        weights = torch.cat([weights, weights.mean(1, keepdim=True)], 1)
        maps.append(similarity(iq_x, iq_y, c).sum(1, keepdim=True) / 2)
    sim = torch.cat(maps, 1)
    eps = torch.finfo(sim.dtype).eps
    local = (sim * alpha).sigmoid()
    total = weights.sum(dim=(1, 2, 3))
    score = torch.where(
        total > 0, ((local * weights).sum(dim=(1, 2, 3)) + eps) / (total + eps),
        # two flat frames (a fade from black) give no weight anywhere: the formula reads
        # 0/0 (PIQ returns inf); the plain mean of the local similarities is its limit
        local.mean(dim=(1, 2, 3)))
    return (torch.log(score / (1 - score)) / alpha) ** 2
