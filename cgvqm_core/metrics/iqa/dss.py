"""DSS (Balanis et al. 2015): DCT subband similarity, on luma (Y of YIQ, 0..255).

8x8 block DCT; each subband whose Gaussian weight (sigma 1.55) is at least 0.01 is compared
by its local variance similarity (3x3 Gaussian, sigma 1.5; constants 1000 for DC, 300 for AC),
pooled over the worst 5 % of positions; the DC band adds a structure term.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ._common import check_pair, gaussian_kernel, luma_yiq


def _dct_matrix(n: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    p = torch.arange(1, n, dtype=dtype, device=device).view(n - 1, 1)
    q = torch.arange(1, 2 * n, 2, dtype=dtype, device=device)
    first = math.sqrt(1 / n) * torch.ones(1, n, dtype=dtype, device=device)
    return torch.cat([first, math.sqrt(2 / n) * torch.cos(math.pi / (2 * n) * p * q)], 0)


def _block_dct(x: torch.Tensor, n: int) -> torch.Tensor:
    """Blockwise 2-D DCT of (B, 1, H, W) with H, W multiples of n, coefficients in place."""
    B, _, H, W = x.shape
    d = _dct_matrix(n, x.dtype, x.device)
    blocks = x.view(B, H // n, n, W // n, n).permute(0, 1, 3, 2, 4)
    coef = d @ blocks @ d.t()
    return coef.permute(0, 1, 3, 2, 4).reshape(B, 1, H, W)


def _subband(x: torch.Tensor, y: torch.Tensor, dc: bool, ksize: int, sigma: float,
             percentile: float) -> torch.Tensor:
    c = 1000.0 if dc else 300.0
    k = gaussian_kernel(ksize, sigma, dtype=x.dtype, device=x.device).view(1, 1, ksize, ksize)
    p = ksize // 2
    mx, my = F.conv2d(x, k, padding=p), F.conv2d(y, k, padding=p)
    sxx = torch.clamp(F.conv2d(x * x, k, padding=p) - mx**2, min=0)
    syy = torch.clamp(F.conv2d(y * y, k, padding=p) - my**2, min=0)
    left = (2 * torch.sqrt(sxx * syy) + c) / (sxx + syy + c)
    n = round(percentile * left.size(-2) * left.size(-1))
    if n < 1:
        raise ValueError(f"DSS pools the worst {percentile:.0%} of {left.size(-2)}x"
                         f"{left.size(-1)} DCT blocks, which is none: the image is too small")
    sim = torch.sort(left.flatten(1)).values[:, :n].mean(1)
    if dc:
        sxy = F.conv2d(x * y, k, padding=p) - mx * my
        right = (sxy + c) / (torch.sqrt(sxx * syy) + c)
        sim = sim * torch.sort(right.flatten(1)).values[:, :n].mean(1)
    return sim


def dss(test: torch.Tensor, ref: torch.Tensor, *, dct_size: int = 8, sigma_weight: float = 1.55,
        kernel_size: int = 3, sigma_similarity: float = 1.5,
        percentile: float = 0.05) -> torch.Tensor:
    """DSS of each image (higher is better)."""
    check_pair(test, ref)
    if min(test.shape[-2:]) < max(dct_size, kernel_size):
        raise ValueError("DSS needs images at least as large as its DCT block")
    x, y = luma_yiq(test * 255.0), luma_yiq(ref * 255.0)
    H = dct_size * (x.size(-2) // dct_size)
    W = dct_size * (x.size(-1) // dct_size)
    x, y = _block_dct(x[..., :H, :W], dct_size), _block_dct(y[..., :H, :W], dct_size)
    r = torch.arange(1, dct_size + 1, dtype=x.dtype, device=x.device) - 0.5
    weight = torch.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * sigma_weight**2))
    weight = torch.where(weight < 0.01, torch.zeros_like(weight), weight)
    sims = torch.zeros(x.size(0), dct_size, dct_size, dtype=x.dtype, device=x.device)
    for m in range(dct_size):
        for n in range(dct_size):
            if weight[m, n] == 0:
                continue
            sims[:, m, n] = _subband(x[..., m::dct_size, n::dct_size],
                                     y[..., m::dct_size, n::dct_size], m == 0 and n == 0,
                                     kernel_size, sigma_similarity, percentile)
    eps = torch.finfo(weight.dtype).eps
    return (sims * (weight / weight.sum() + eps)).sum(dim=(1, 2))
