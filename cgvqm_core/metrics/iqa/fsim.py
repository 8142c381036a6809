"""FSIM and FSIMc (Zhang et al. 2011): phase congruency and gradient similarity.

Images on the 0..255 scale are average-pooled by max(1, round(min(H, W) / 256)); phase
congruency of the luma (Y of YIQ) from log-Gabor filters (4 scales from a 6-pixel
wavelength, factor 2, sigma_f 0.55; 4 orientations, angular spread pi / (4 x 1.2); noise
threshold k = 2) and the Scharr gradient magnitude are compared with constants 0.85 and 160;
FSIMc adds the I and Q chrominance similarity (constants 200, exponent 0.03). PIQ's default,
and this one's, is the chromatic FSIMc on RGB input.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ._common import (
    YIQ,
    check_pair,
    colour_transform,
    frequency_grid,
    gradient_magnitude,
    scharr,
    similarity,
)


def _filters(h: int, w: int, scales: int, orientations: int, min_length: int, mult: int,
             sigma_f: float, delta_theta: float, dtype: torch.dtype,
             device: torch.device) -> torch.Tensor:
    """(orientations * scales, H, W) log-Gabor x angular spread filters in FFT layout."""
    theta_sigma = math.pi / (orientations * delta_theta)
    gx, gy = frequency_grid(h, w, dtype=dtype, device=device)
    radius = torch.sqrt(gx**2 + gy**2)
    theta = torch.atan2(-gy, gx)
    lowpass = torch.fft.ifftshift(1.0 / (1.0 + (radius / 0.45) ** 30))
    radius = torch.fft.ifftshift(radius)
    theta = torch.fft.ifftshift(theta)
    radius[0, 0] = 1
    sin_t, cos_t = torch.sin(theta), torch.cos(theta)
    gabors = []
    for s in range(scales):
        f0 = 1.0 / (min_length * mult**s)
        g = torch.exp(-torch.log(radius / f0) ** 2 / (2 * math.log(sigma_f) ** 2)) * lowpass
        g[0, 0] = 0
        gabors.append(g)
    out = []
    for o in range(orientations):
        a = o * math.pi / orientations
        ds = sin_t * math.cos(a) - cos_t * math.sin(a)
        dc = cos_t * math.cos(a) + sin_t * math.sin(a)
        spread = torch.exp(-torch.atan2(ds, dc).abs() ** 2 / (2 * theta_sigma**2))
        out += [spread * g for g in gabors]
    return torch.stack(out)


def _phase_congruency(x: torch.Tensor, filters: torch.Tensor, scales: int, orientations: int,
                      k: float) -> torch.Tensor:
    """Phase congruency (B, 1, H, W) of a one-channel image (Kovesi's measure)."""
    eps = torch.finfo(x.dtype).eps
    B, _, H, W = x.shape
    spatial = torch.fft.ifft2(filters).real * math.sqrt(H * W)
    eo = torch.view_as_real(torch.fft.ifft2(torch.fft.fft2(x) * filters))
    eo = eo.view(B, orientations, scales, H, W, 2)
    amplitude = eo.pow(2).sum(-1).sqrt()
    em_n = (filters.view(1, orientations, scales, H, W)[:, :, :1] ** 2).sum(dim=(-2, -1),
                                                                            keepdim=True)
    even, odd = eo[..., 0], eo[..., 1]
    sum_e = even.sum(2, keepdim=True)
    sum_o = odd.sum(2, keepdim=True)
    norm = torch.sqrt(sum_e**2 + sum_o**2) + eps
    mean_e, mean_o = sum_e / norm, sum_o / norm
    energy = (even * mean_e + odd * mean_o - (even * mean_o - odd * mean_e).abs()).sum(
        2, keepdim=True)
    first = eo[:, :, :1].pow(2).sum(-1).reshape(B, orientations, 1, 1, H * W)
    median = torch.median(first, dim=-1, keepdim=True).values
    noise_power = (-median / math.log(0.5)) / em_n
    spatial = spatial.view(1, orientations, scales, H, W)
    sum_an2 = (spatial**2).sum(-3, keepdim=True).sum(dim=(-1, -2), keepdim=True)
    cross = torch.zeros(1, orientations, 1, H, W, dtype=x.dtype, device=x.device)
    for s in range(scales - 1):
        cross = cross + (spatial[:, :, s:s + 1] * spatial[:, :, s + 1:]).sum(-3, keepdim=True)
    cross = cross.sum(dim=(-1, -2), keepdim=True)
    tau = torch.sqrt((2 * noise_power * sum_an2 + 4 * noise_power * cross) / 2)
    threshold = (tau * math.sqrt(math.pi / 2)
                 + k * torch.sqrt((2 - math.pi / 2) * tau**2)) / 1.7
    energy = torch.clamp(energy - threshold, min=0)
    pc = (energy.sum(dim=(1, 2)) + eps) / (amplitude.sum(dim=(1, 2)) + eps)
    return pc.unsqueeze(1)


def fsim(test: torch.Tensor, ref: torch.Tensor, *, chromatic: bool = True, scales: int = 4,
         orientations: int = 4, min_length: int = 6, mult: int = 2, sigma_f: float = 0.55,
         delta_theta: float = 1.2, k: float = 2.0) -> torch.Tensor:
    """FSIMc (or FSIM with ``chromatic=False``) of each image (higher is better)."""
    check_pair(test, ref)
    x, y = test * 255.0, ref * 255.0
    f = max(1, round(min(x.shape[-2:]) / 256))
    x, y = F.avg_pool2d(x, f), F.avg_pool2d(y, f)
    if x.size(1) == 3:
        xq, yq = colour_transform(x, YIQ), colour_transform(y, YIQ)
        xl, yl = xq[:, :1], yq[:, :1]
    else:
        if chromatic:
            raise ValueError("FSIMc needs RGB images")
        xl, yl = x, y
    filt = _filters(xl.size(-2), xl.size(-1), scales, orientations, min_length, mult, sigma_f,
                    delta_theta, xl.dtype, xl.device)
    pcx = _phase_congruency(xl, filt, scales, orientations, k)
    pcy = _phase_congruency(yl, filt, scales, orientations, k)
    kern = scharr(xl.dtype, xl.device)
    gm = similarity(gradient_magnitude(xl, kern), gradient_magnitude(yl, kern), 160)
    pc_max = torch.maximum(pcx, pcy)
    s = gm * similarity(pcx, pcy, 0.85) * pc_max
    if chromatic:
        s = s * (similarity(xq[:, 1:2], yq[:, 1:2], 200)
                 * similarity(xq[:, 2:], yq[:, 2:], 200)).abs() ** 0.03
    return s.sum(dim=(1, 2, 3)) / pc_max.sum(dim=(1, 2, 3))
