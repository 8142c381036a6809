"""SSIM (Wang et al. 2004) and MS-SSIM (Wang et al. 2003), per RGB channel then averaged.

SSIM: 11x11 Gaussian window (sigma 1.5) without padding, K1 = 0.01, K2 = 0.03, on images
first average-pooled by f = max(1, round(min(H, W) / 256)) (the authors' recommended
down-sampling, also PIQ's default). MS-SSIM: five scales with weights 0.0448, 0.2856, 0.3001,
0.2363, 0.1333, each scale halved by 2x2 average pooling after replicate padding of odd sizes;
it needs images of at least (11 - 1) * 2^4 + 1 = 161 pixels in both directions.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ._common import check_pair, depthwise, gaussian_kernel

MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)


def ssim_maps(x: torch.Tensor, y: torch.Tensor, kernel: torch.Tensor, k1: float = 0.01,
              k2: float = 0.03) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-channel mean SSIM and contrast-structure term (B, C), data in [0, 1]."""
    if x.size(-1) < kernel.size(-1) or x.size(-2) < kernel.size(-2):
        raise ValueError(f"image {tuple(x.shape[-2:])} is smaller than the SSIM window")
    c1, c2 = k1**2, k2**2
    mx, my = depthwise(x, kernel), depthwise(y, kernel)
    mxx, myy, mxy = mx * mx, my * my, mx * my
    sxx = depthwise(x * x, kernel) - mxx
    syy = depthwise(y * y, kernel) - myy
    sxy = depthwise(x * y, kernel) - mxy
    cs = (2.0 * sxy + c2) / (sxx + syy + c2)
    s = (2.0 * mxy + c1) / (mxx + myy + c1) * cs
    return s.mean(dim=(-1, -2)), cs.mean(dim=(-1, -2))


def ssim(test: torch.Tensor, ref: torch.Tensor, *, kernel_size: int = 11,
         sigma: float = 1.5, downsample: bool = True) -> torch.Tensor:
    """Mean SSIM over pixels and channels of each image (higher is better, 1 = identical)."""
    check_pair(test, ref)
    f = max(1, round(min(test.shape[-2:]) / 256))
    if downsample and f > 1:
        test, ref = F.avg_pool2d(test, f), F.avg_pool2d(ref, f)
    k = gaussian_kernel(kernel_size, sigma, dtype=test.dtype, device=test.device)
    s, _ = ssim_maps(test, ref, k)
    return s.mean(1)


def ms_ssim_min_size(kernel_size: int = 11, scales: int = len(MS_SSIM_WEIGHTS)) -> int:
    """Smallest height and width MS-SSIM (and IW-SSIM) accept: (kernel - 1) 2^(scales-1) + 1."""
    return (kernel_size - 1) * 2 ** (scales - 1) + 1


def ms_ssim(test: torch.Tensor, ref: torch.Tensor, *, kernel_size: int = 11,
            sigma: float = 1.5) -> torch.Tensor:
    """Multi-scale SSIM of each image (higher is better); ValueError below the minimum size."""
    check_pair(test, ref)
    need = ms_ssim_min_size(kernel_size)
    if min(test.shape[-2:]) < need:
        raise ValueError(f"MS-SSIM needs at least {need}x{need} pixels, got "
                         f"{test.size(-1)}x{test.size(-2)}")
    k = gaussian_kernel(kernel_size, sigma, dtype=test.dtype, device=test.device)
    w = torch.tensor(MS_SSIM_WEIGHTS, dtype=test.dtype, device=test.device)
    x, y = test, ref
    terms = []
    for level in range(len(MS_SSIM_WEIGHTS)):
        if level:
            p = max(x.size(2) % 2, x.size(3) % 2)
            if p:
                x = F.pad(x, [p, 0, p, 0], mode="replicate")
                y = F.pad(y, [p, 0, p, 0], mode="replicate")
            x, y = F.avg_pool2d(x, 2), F.avg_pool2d(y, 2)
        s, cs = ssim_maps(x, y, k)
        terms.append(s if level == len(MS_SSIM_WEIGHTS) - 1 else cs)
    t = torch.relu(torch.stack(terms))  # (scales, B, C)
    return torch.prod(t ** w.view(-1, 1, 1), dim=0).mean(1)
