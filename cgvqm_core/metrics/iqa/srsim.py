"""SR-SIM (Zhang & Li 2012): spectral-residual visual saliency and gradient similarity.

Images on the 0..255 scale, average-pooled by max(1, round(min(H, W) / 256)) after zero
padding; on the luma (Y of YIQ) the spectral-residual saliency is computed at 1/4 size (MATLAB
bicubic), smoothed by a 10x10 Gaussian (sigma 3.8), normalised to [0, 1] per image and brought
back to size; Scharr gradients; constants 0.40 (saliency) and 225 (gradient), gradient
exponent 0.5. PIQ's default (and this one's) is the luma-only SR-SIM.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ._common import (
    YIQ,
    check_pair,
    colour_transform,
    gaussian_kernel,
    gradient_magnitude,
    per_image_minmax,
    scharr,
    similarity,
)
from ._resize import imresize


def _saliency(x: torch.Tensor, scale: float = 0.25, box: int = 3, sigma: float = 3.8,
              gsize: int = 10) -> torch.Tensor:
    eps = torch.finfo(x.dtype).eps
    for k in (box, gsize):
        if x.size(-1) * scale < k or x.size(-2) * scale < k:
            raise ValueError(f"SR-SIM needs images of at least {int(k / scale)} pixels "
                             "after its internal down-sampling")
    small = imresize(x, scale=scale)
    spec = torch.fft.fft2(small)
    log_amp = torch.log(spec.abs() + eps)
    phase = torch.angle(spec)
    p = box // 2
    padded = F.pad(log_amp, [(box - 1) // 2, p, (box - 1) // 2, p], mode="replicate") if p \
        else log_amp
    residual = log_amp - F.avg_pool2d(padded, box, stride=1)
    sal = torch.fft.ifft2(torch.polar(torch.exp(residual), phase)).abs() ** 2
    k = gaussian_kernel(gsize, sigma, dtype=sal.dtype, device=sal.device)
    if gsize % 2 == 0:  # centre an even kernel by a leading zero row and column
        k = F.pad(k, [1, 0, 1, 0])
    n = k.size(-1)
    sal = F.conv2d(sal, k.view(1, 1, n, n), padding=(n - 1) // 2)
    sal = per_image_minmax(sal, eps)
    return imresize(sal, size=tuple(x.shape[-2:]))


def srsim(test: torch.Tensor, ref: torch.Tensor, *, chromatic: bool = False) -> torch.Tensor:
    """SR-SIM (or SR-SIMc with ``chromatic=True``) of each image (higher is better)."""
    check_pair(test, ref)
    x, y = test * 255.0, ref * 255.0
    f = max(1, round(min(x.shape[-2:]) / 256))
    if f // 2:
        x = F.pad(x, [(f - 1) // 2, f // 2, (f - 1) // 2, f // 2])
        y = F.pad(y, [(f - 1) // 2, f // 2, (f - 1) // 2, f // 2])
    x, y = F.avg_pool2d(x, f), F.avg_pool2d(y, f)
    if x.size(1) == 3:
        xq, yq = colour_transform(x, YIQ), colour_transform(y, YIQ)
        xl, yl = xq[:, :1], yq[:, :1]
    else:
        if chromatic:
            raise ValueError("SR-SIMc needs RGB images")
        xl, yl = x, y
    sx, sy = _saliency(xl), _saliency(yl)
    kern = scharr(xl.dtype, xl.device)
    gm = similarity(gradient_magnitude(xl, kern), gradient_magnitude(yl, kern), 225)
    s_max = torch.maximum(sx, sy)
    s = similarity(sx, sy, 0.4) * gm**0.5 * s_max
    if chromatic:
        s = s * (similarity(xq[:, 1:2], yq[:, 1:2], 200)
                 * similarity(xq[:, 2:], yq[:, 2:], 200)).abs() ** 0.03
    eps = torch.finfo(s.dtype).eps
    return s.sum(dim=(1, 2, 3)) / (s_max.sum(dim=(1, 2, 3)) + eps)
