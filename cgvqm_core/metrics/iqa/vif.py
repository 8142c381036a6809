"""VIFp, the pixel-domain Visual Information Fidelity (Sheikh & Bovik 2006), on luma.

Luma is BT.601 (0.299 R + 0.587 G + 0.114 B) on the 0..255 scale; four scales with Gaussian
windows of 17, 9, 5 and 3 pixels (sigma = size / 5), each coarser scale filtered and
decimated by 2; HVS noise variance 2. Needs at least 41x41 pixels.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ._common import check_pair, gaussian_kernel

MIN_SIZE = 41
EPS = 1e-8


def vif_p(test: torch.Tensor, ref: torch.Tensor, *, sigma_n_sq: float = 2.0) -> torch.Tensor:
    """VIFp of each image: information the test keeps of the reference's (higher is better,
    1 = identical; above 1 for contrast enhancement)."""
    check_pair(test, ref)
    if min(test.shape[-2:]) < MIN_SIZE:
        raise ValueError(f"VIFp needs at least {MIN_SIZE}x{MIN_SIZE} pixels")
    w = torch.tensor((0.299, 0.587, 0.114), dtype=test.dtype, device=test.device).view(1, 3, 1, 1)
    # the distorted image is PIQ's x, the reference its y: information is measured about y
    x = (test * 255.0 * w).sum(1, keepdim=True) if test.size(1) == 3 else test * 255.0
    y = (ref * 255.0 * w).sum(1, keepdim=True) if ref.size(1) == 3 else ref * 255.0
    num = torch.zeros(x.size(0), dtype=x.dtype, device=x.device)
    den = torch.zeros_like(num)
    for scale in range(4):
        n = 2 ** (4 - scale) + 1
        k = gaussian_kernel(n, n / 5, dtype=x.dtype, device=x.device).view(1, 1, n, n)
        if scale:
            x = F.conv2d(x, k)[:, :, ::2, ::2]
            y = F.conv2d(y, k)[:, :, ::2, ::2]
        mx, my = F.conv2d(x, k), F.conv2d(y, k)
        sxx = torch.relu(F.conv2d(x * x, k) - mx * mx)
        syy = torch.relu(F.conv2d(y * y, k) - my * my)
        sxy = F.conv2d(x * y, k) - mx * my
        g = sxy / (syy + EPS)
        sv = sxx - g * sxy
        ok_y = syy >= EPS
        g = torch.where(ok_y, g, torch.zeros_like(g))
        sv = torch.where(ok_y, sv, sxx)
        syy = torch.where(ok_y, syy, torch.zeros_like(syy))
        ok_x = sxx >= EPS
        g = torch.where(ok_x, g, torch.zeros_like(g))
        sv = torch.where(ok_x, sv, torch.zeros_like(sv))
        sv = torch.where(g >= 0, sv, sxx)
        g = torch.relu(g)
        sv = torch.where(sv > EPS, sv, torch.full_like(sv, EPS))
        num = num + torch.log10(1.0 + g**2 * syy / (sv + sigma_n_sq)).sum(dim=(1, 2, 3))
        den = den + torch.log10(1.0 + syy / sigma_n_sq).sum(dim=(1, 2, 3))
    return (num + EPS) / (den + EPS)
