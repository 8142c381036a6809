"""Edge-aware a-trous wavelet denoiser (the spatial part of SVGF-style real-time denoisers).

Noise in the synthetic renders is in the lighting, so the filter works on demodulated
irradiance (colour / albedo) and puts the texture back afterwards. Edge-stopping weights on
normals, depth and luminance keep geometry edges; what remains are the family's typical
artefacts: low-frequency blotches where few samples disagree, over-blurred lighting detail.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .color import luminance

_B3 = np.array([1.0, 4.0, 6.0, 4.0, 1.0], dtype=np.float32) / 16.0


def atrous_denoise(
    colour: np.ndarray,
    albedo: np.ndarray,
    normal: np.ndarray,
    depth: np.ndarray,
    hit: np.ndarray,
    *,
    iterations: int = 4,
    sigma_normal: float = 64.0,
    sigma_depth: float = 0.5,
    sigma_luminance: float = 4.0,
) -> np.ndarray:
    """Denoise linear frames (…, H, W, 3) using their G-buffers (…, H, W[, 3]) as guide."""
    hit = hit.astype(bool)
    safe_albedo = np.maximum(albedo, 1e-3).astype(np.float32)
    irr = np.where(hit[..., None], colour / safe_albedo, colour).astype(np.float32)
    h, w = irr.shape[-3], irr.shape[-2]
    # luminance edge-stopping scaled by the local noise level, as SVGF does with variance
    lum0 = luminance(irr)
    spatial = (0.0,) * (lum0.ndim - 2) + (1.5, 1.5)
    mean = ndimage.gaussian_filter(lum0, spatial, mode="nearest")
    var = np.maximum(ndimage.gaussian_filter(lum0 * lum0, spatial, mode="nearest") - mean**2, 0)
    lum_scale = (sigma_luminance * np.sqrt(var) + 1e-2).astype(np.float32)
    for it in range(iterations):
        step = 1 << it
        pad = 2 * step

        def pad_img(a: np.ndarray, channels: bool, pad: int = pad) -> np.ndarray:
            widths = [(0, 0)] * a.ndim
            ax = a.ndim - 3 if channels else a.ndim - 2
            widths[ax] = widths[ax + 1] = (pad, pad)
            return np.pad(a, widths, mode="edge")

        p_irr = pad_img(irr, True)
        p_lum = pad_img(luminance(irr), False)
        p_n = pad_img(normal, True)
        p_z = pad_img(depth, False)
        p_hit = pad_img(hit, False)
        lum = luminance(irr)
        num = np.zeros_like(irr)
        den = np.zeros(irr.shape[:-1], dtype=np.float32)
        for i, ky in enumerate(_B3):
            for j, kx in enumerate(_B3):
                y0, x0 = pad + (i - 2) * step, pad + (j - 2) * step
                ys, xs = slice(y0, y0 + h), slice(x0, x0 + w)
                cos = np.einsum("...c,...c->...", normal, p_n[..., ys, xs, :])
                wgt = (ky * kx) * np.power(np.maximum(cos, 0.0), sigma_normal)
                wgt *= np.exp(-np.abs(depth - p_z[..., ys, xs]) / (sigma_depth * step))
                wgt *= np.exp(-np.abs(lum - p_lum[..., ys, xs]) / lum_scale)
                wgt *= p_hit[..., ys, xs] == hit
                num += wgt[..., None] * p_irr[..., ys, xs, :]
                den += wgt
        irr = num / np.maximum(den, 1e-8)[..., None]
    return np.where(hit[..., None], irr * safe_albedo, colour).astype(np.float32)
