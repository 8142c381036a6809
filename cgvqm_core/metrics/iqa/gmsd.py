"""GMSD (Xue et al. 2014) and MS-GMSD (Zhang et al. 2017): gradient magnitude similarity
deviation, lower is better (0 = identical).

GMSD: luma (Y of YIQ) in [0, 1], halved by 2x2 average pooling, Prewitt gradients, constant
170 / 255^2. MS-GMSD: luma on the 0..255 scale, four scales (weights 0.096, 0.596, 0.289,
0.019) with constant 170 and the alpha = 0.5 similarity variant; PIQ's default (and this
one's) leaves out the chromatic term.
"""

from __future__ import annotations

import torch

from ._common import (
    YIQ,
    check_pair,
    colour_transform,
    gradient_magnitude,
    halve,
    prewitt,
    similarity,
)

MS_GMSD_WEIGHTS = (0.096, 0.596, 0.289, 0.019)


def _deviation(x: torch.Tensor, y: torch.Tensor, c: float, alpha: float = 0.0) -> torch.Tensor:
    k = prewitt(x.dtype, x.device)
    gms = similarity(gradient_magnitude(x, k), gradient_magnitude(y, k), c, alpha)
    return (gms - gms.mean(dim=(1, 2, 3), keepdim=True)).pow(2).mean(dim=(1, 2, 3)).sqrt()


def gmsd(test: torch.Tensor, ref: torch.Tensor, *, c: float = 170 / 255.0**2) -> torch.Tensor:
    """GMSD of each image (lower is better)."""
    check_pair(test, ref)
    x, y = test, ref
    if x.size(1) == 3:
        x, y = colour_transform(x, YIQ)[:, :1], colour_transform(y, YIQ)[:, :1]
    return _deviation(halve(x), halve(y), c)


def ms_gmsd(test: torch.Tensor, ref: torch.Tensor, *, chromatic: bool = False,
            alpha: float = 0.5, beta1: float = 0.01, beta2: float = 0.32, beta3: float = 15.0,
            c: float = 170.0) -> torch.Tensor:
    """MS-GMSD (MS-GMSDc with ``chromatic=True``) of each image (lower is better)."""
    check_pair(test, ref)
    n = len(MS_GMSD_WEIGHTS)
    if min(test.shape[-2:]) < 2**n + 1:
        raise ValueError(f"MS-GMSD needs at least {2**n + 1}x{2**n + 1} pixels")
    x, y = test * 255.0, ref * 255.0
    if x.size(1) == 3:
        x, y = colour_transform(x, YIQ), colour_transform(y, YIQ)
    devs = []
    for s in range(n):
        if s:
            x, y = halve(x), halve(y)
        devs.append(_deviation(x[:, :1], y[:, :1], c, alpha))
    w = torch.tensor(MS_GMSD_WEIGHTS, dtype=x.dtype, device=x.device)
    score = torch.sqrt((w.view(1, n) * torch.stack(devs, dim=1) ** 2).sum(1))
    if chromatic:
        if x.size(1) != 3:
            raise ValueError("MS-GMSDc needs RGB images")
        rmse = torch.sqrt(((x[:, 1:] - y[:, 1:]) ** 2).mean(dim=(2, 3)))
        chroma = torch.sqrt((rmse**2).sum(1))
        gamma = 2 / (1 + beta2 * torch.exp(-beta3 * score)) - 1
        score = gamma * score + (1 - gamma) * beta1 * chroma
    return score
