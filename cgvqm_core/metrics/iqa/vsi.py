"""VSI (Zhang et al. 2014): visual-saliency-induced index, on RGB.

Saliency is SDSP (frequency, location and colour priors) computed at 256x256 in CIELAB
(sRGB, D50 white as PIQ does it); images are pooled by max(1, round(min(H, W) / 256)) with
replicate padding; Scharr gradients of the L channel of the LMN opponent space; constants
1.27 (saliency), 386 (gradient), 130 (chroma), exponents alpha 0.4 and beta 0.02.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ._common import (
    LMN,
    check_pair,
    colour_transform,
    frequency_grid,
    gradient_magnitude,
    scharr,
    similarity,
)

SRGB_TO_XYZ = ((0.4124564, 0.3575761, 0.1804375), (0.2126729, 0.7151522, 0.0721750),
               (0.0193339, 0.1191920, 0.9503041))
D50_WHITE = (0.9642119944211994, 1.0, 0.8251882845188288)


def rgb_to_lab(x: torch.Tensor) -> torch.Tensor:
    """sRGB in [0, 1] -> CIELAB relative to D50 (as PIQ's rgb2lab)."""
    lin = torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    xyz = colour_transform(lin, SRGB_TO_XYZ)
    t = xyz / torch.tensor(D50_WHITE, dtype=x.dtype, device=x.device).view(1, 3, 1, 1)
    f = torch.where(t > 0.008856, t ** (1.0 / 3.0), (903.3 * t + 16.0) / 116.0)
    L = 116.0 * f[:, 1:2] - 16.0
    a = 500.0 * (f[:, :1] - f[:, 1:2])
    b = 200.0 * (f[:, 1:2] - f[:, 2:])
    return torch.cat([L, a, b], 1)


def _log_gabor(gx: torch.Tensor, gy: torch.Tensor, omega_0: float,
               sigma_f: float) -> torch.Tensor:
    r = torch.fft.ifftshift(torch.sqrt(gx**2 + gy**2) * (torch.sqrt(gx**2 + gy**2) <= 0.5))
    r[0, 0] = 1
    lg = torch.exp(-torch.log(r / omega_0) ** 2 / (2 * sigma_f**2))
    lg[0, 0] = 0
    return lg


def sdsp(x: torch.Tensor, *, omega_0: float = 0.021, sigma_f: float = 1.34,
         sigma_d: float = 145.0, sigma_c: float = 0.001) -> torch.Tensor:
    """SDSP saliency (B, 1, H, W) in [0, 1] of RGB images on the 0..255 scale."""
    size = x.shape[-2:]
    n = 256
    lab = rgb_to_lab(F.interpolate(x, size=(n, n), mode="bilinear", align_corners=False) / 255)
    gx, gy = frequency_grid(n, n, dtype=lab.dtype, device=lab.device)
    lg = _log_gabor(gx, gy, omega_0, sigma_f).view(1, 1, n, n)
    s_f = torch.fft.ifft2(torch.fft.fft2(lab) * lg).real.pow(2).sum(1, keepdim=True).sqrt()
    s_d = torch.exp(-((gx * n + 1) ** 2 + (gy * n + 1) ** 2) / sigma_d**2).view(1, 1, n, n)
    eps = torch.finfo(lab.dtype).eps
    lo = lab.amin(dim=(-1, -2), keepdim=True)
    hi = lab.amax(dim=(-1, -2), keepdim=True)
    normed = (lab - lo) / (hi - lo + eps)
    s_c = 1 - torch.exp(-normed[:, 1:].pow(2).sum(1, keepdim=True) / sigma_c**2)
    vs = F.interpolate(s_f * s_d * s_c, size=size, mode="bilinear", align_corners=True)
    lo = vs.amin(dim=(-1, -2), keepdim=True)
    hi = vs.amax(dim=(-1, -2), keepdim=True)
    return (vs - lo) / (hi - lo + eps)


def vsi(test: torch.Tensor, ref: torch.Tensor, *, c1: float = 1.27, c2: float = 386.0,
        c3: float = 130.0, alpha: float = 0.4, beta: float = 0.02) -> torch.Tensor:
    """VSI of each image (higher is better)."""
    check_pair(test, ref)
    if test.size(1) == 1:
        test, ref = test.repeat(1, 3, 1, 1), ref.repeat(1, 3, 1, 1)
    x, y = test * 255.0, ref * 255.0
    vx, vy = sdsp(x), sdsp(y)
    xl, yl = colour_transform(x, LMN), colour_transform(y, LMN)
    k = max(1, round(min(vx.shape[-2:]) / 256))
    p = k // 2
    if p:
        pads = [p, (k - 1) // 2, p, (k - 1) // 2]
        vx, vy, xl, yl = (F.pad(t, pads, mode="replicate") for t in (vx, vy, xl, yl))
    vx, vy, xl, yl = (F.avg_pool2d(t, k) for t in (vx, vy, xl, yl))
    kern = scharr(xl.dtype, xl.device)
    s_gm = similarity(gradient_magnitude(xl[:, :1], kern), gradient_magnitude(yl[:, :1], kern),
                      c2)
    s_c = similarity(xl[:, 1:2], yl[:, 1:2], c3) * similarity(xl[:, 2:], yl[:, 2:], c3)
    # real part of s_c^beta for negative s_c (the MATLAB code's complex power)
    chroma = s_c.abs() ** beta * torch.cos(torch.atan2(torch.zeros_like(s_c), s_c) * beta)
    vs_max = torch.maximum(vx, vy)
    s = similarity(vx, vy, c1) * s_gm.pow(alpha) * chroma * vs_max
    eps = torch.finfo(vs_max.dtype).eps
    return ((s.sum(dim=(-1, -2)) + eps) / (vs_max.sum(dim=(-1, -2)) + eps)).squeeze(-1)
