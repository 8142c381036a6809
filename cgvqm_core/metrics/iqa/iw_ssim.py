"""Information-weighted SSIM (Wang & Li 2011) on luma, as in the authors' MATLAB code.

The luma (Y of YIQ, 0..255) is split into a five-level Laplacian pyramid (binomial 5-tap
filter times sqrt 2, reflect padding); at every level but the coarsest the contrast-structure
map is pooled with weights from a Gaussian scale mixture model of the reference's local
information content (3x3 blocks plus the parent coefficient, noise variance 0.4); the coarsest
level uses plain SSIM. Scale weights as MS-SSIM's. Needs at least 161x161 pixels.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ._common import check_pair, depthwise, gaussian_kernel, luma_yiq
from .ssim import MS_SSIM_WEIGHTS, ms_ssim_min_size

BLOCK = 3
SIGMA_NSQ = 0.4


def _blur_1d(x: torch.Tensor, k: torch.Tensor, dim: int) -> torch.Tensor:
    """Reflect-pad and filter along width (dim -1) or height (dim -2)."""
    n = k.numel()
    before, after = (n - 1) // 2, n - 1 - (n - 1) // 2
    if dim == -1:
        return F.conv2d(F.pad(x, [before, after, 0, 0], mode="reflect"), k.view(1, 1, 1, n))
    return F.conv2d(F.pad(x, [0, 0, before, after], mode="reflect"), k.view(1, 1, n, 1))


def _pyramid_step(x: torch.Tensor, k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(low-pass half-size image, high-pass residual at full size)."""
    h, w = x.shape[-2:]
    lo = x
    if w > 1:
        lo = _blur_1d(lo, k, -1)[..., ::2]
    if h > 1:
        lo = _blur_1d(lo, k, -2)[..., ::2, :]
    up = lo
    if w > 1:
        z = up.new_zeros(*up.shape[:-1], 2 * up.size(-1))
        z[..., ::2] = up
        up = _blur_1d(z, k, -1)[..., :w]
    if h > 1:
        z = up.new_zeros(*up.shape[:-2], 2 * up.size(-2), up.size(-1))
        z[..., ::2, :] = up
        up = _blur_1d(z, k, -2)[..., :h, :]
    return lo, x - up


def _ssim_maps(x: torch.Tensor, y: torch.Tensor, kernel: torch.Tensor,
               L: float = 255.0) -> tuple[torch.Tensor, torch.Tensor]:
    c1, c2 = (0.01 * L) ** 2, (0.03 * L) ** 2
    mx, my = depthwise(x, kernel), depthwise(y, kernel)
    mxx, myy, mxy = mx * mx, my * my, mx * my
    sxx = torch.relu(depthwise(x * x, kernel) - mxx)
    syy = torch.relu(depthwise(y * y, kernel) - myy)
    sxy = depthwise(x * y, kernel) - mxy
    cs = (2.0 * sxy + c2) / (sxx + syy + c2)
    return (2.0 * mxy + c1) / (mxx + myy + c1) * cs, cs


def _enlarge_parent(p: torch.Tensor) -> torch.Tensor:
    """The parent band brought to twice its size (bilinear with linear extrapolation)."""
    h, w = p.shape[-2:]
    inner = F.interpolate(p, size=(4 * h - 3, 4 * w - 3), mode="bilinear", align_corners=False)
    t = p.new_zeros(p.size(0), 1, 4 * h - 1, 4 * w - 1)
    t[:, :, 1:-1, 1:-1] = inner
    t[:, :, 0, :] = 2 * t[:, :, 1, :] - t[:, :, 2, :]
    t[:, :, -1, :] = 2 * t[:, :, -2, :] - t[:, :, -3, :]
    t[:, :, :, 0] = 2 * t[:, :, :, 1] - t[:, :, :, 2]
    t[:, :, :, -1] = 2 * t[:, :, :, -2] - t[:, :, :, -3]
    return t[:, :, ::2, ::2]


def _information_content(x: torch.Tensor, y: torch.Tensor, parent: torch.Tensor | None
                         ) -> torch.Tensor:
    """Information-content weight map of one pyramid band (size minus the block border)."""
    eps = torch.finfo(x.dtype).eps
    box = torch.full((BLOCK, BLOCK), 1.0 / BLOCK**2, dtype=x.dtype, device=x.device)
    lo, hi = BLOCK // 2, BLOCK - BLOCK // 2

    def local_mean(a: torch.Tensor) -> torch.Tensor:
        return depthwise(F.pad(a, [lo, hi, lo, hi]), box)

    mx, my = local_mean(x), local_mean(y)
    sxx = torch.relu(local_mean(x * x) - mx * mx)
    syy = torch.relu(local_mean(y * y) - my * my)
    sxy = local_mean(x * y) - mx * my
    g = sxy / (syy + eps)
    vv = sxx - g * sxy
    g = g.masked_fill(syy < eps, 0)
    vv = torch.where(syy < eps, sxx, vv)
    g = g.masked_fill(sxx < eps, 0)
    vv = vv.masked_fill(sxx < eps, 0)

    H, W = y.shape[-2:]
    r = (BLOCK - 1) // 2
    nv, nh = H - BLOCK + 1, W - BLOCK + 1
    cols = []
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            s = torch.roll(y, (dy, dx), dims=(-2, -1))[:, :, r:r + nv, r:r + nh]
            cols.append(s.flatten(-2))
    if parent is not None:
        up = _enlarge_parent(parent)[:, :, :H, :W]
        cols.append(up[:, :, r:r + nv, r:r + nh].flatten(-2))
    Y = torch.stack(cols, dim=-1)  # (B, 1, nv*nh, N)
    N = Y.size(-1)
    cov = Y.transpose(-2, -1) @ Y / (nv * nh)
    ev, vec = torch.linalg.eigh(cov)
    total = ev.sum(-1).view(*ev.shape[:-1], 1, 1)
    pos = torch.diag_embed(ev * (ev > 0))
    pos_sum = pos.sum(dim=(-2, -1), keepdim=True)
    L = pos * total / (pos_sum + (pos_sum == 0))
    cov = vec @ L @ vec.transpose(-2, -1)
    ss = ((Y @ torch.inverse(cov)) * Y / N).sum(-1).view(y.size(0), y.size(1), nv, nh)
    g = g[:, :, r:r + nv, r:r + nh]
    vv = vv[:, :, r:r + nv, r:r + nh]
    lam = torch.diagonal(L, dim1=-2, dim2=-1)[:, :, None, None, :]
    g, vv, ss = g[..., None], vv[..., None], ss[..., None]
    iw = torch.log2(1 + ((vv + (1 + g * g) * SIGMA_NSQ) * ss * lam + SIGMA_NSQ * vv)
                    / (SIGMA_NSQ * SIGMA_NSQ)).sum(-1)
    return iw.masked_fill(iw < eps, 0)


def iw_ssim(test: torch.Tensor, ref: torch.Tensor, *, kernel_size: int = 11,
            sigma: float = 1.5, parent: bool = True) -> torch.Tensor:
    """IW-SSIM of each image (higher is better); ValueError below 161x161 pixels.

    The information-content weights come from the reference (the second argument).
    """
    check_pair(test, ref)
    need = ms_ssim_min_size(kernel_size)
    if min(test.shape[-2:]) < need:
        raise ValueError(f"IW-SSIM needs at least {need}x{need} pixels, got "
                         f"{test.size(-1)}x{test.size(-2)}")
    x, y = luma_yiq(test) * 255.0, luma_yiq(ref) * 255.0
    w = torch.tensor(MS_SSIM_WEIGHTS, dtype=x.dtype, device=x.device)
    w = w / w.sum()
    levels = w.numel()
    iw_pad = math.ceil((kernel_size - 1) / 2) - (BLOCK - 1) // 2
    gk = gaussian_kernel(kernel_size, sigma, dtype=x.dtype, device=x.device)
    bk = torch.tensor([1.0, 4.0, 6.0, 4.0, 1.0], dtype=x.dtype, device=x.device) / 16 * 2**0.5
    x, x_old = _pyramid_step(x, bk)
    y, y_old = _pyramid_step(y, bk)
    pooled = []
    for i in range(levels):
        if i < levels - 2:
            x, x_band = _pyramid_step(x, bk)
            y, y_band = _pyramid_step(y, bk)
        else:
            x_band, y_band = x, y
        s_map, cs_map = _ssim_maps(x_old, y_old, gk)
        if i == levels - 1:
            weight, cs_map = torch.ones_like(cs_map), s_map
        else:
            par = y_band if (parent and i < levels - 2) else None
            weight = _information_content(x_old, y_old, par)
            weight = weight[:, :, iw_pad:-iw_pad, iw_pad:-iw_pad]
        pooled.append((cs_map * weight).sum(dim=(-2, -1)) / weight.sum(dim=(-2, -1)))
        x_old, y_old = x_band, y_band
    t = torch.stack(pooled).abs()  # (levels, B, 1)
    return torch.prod(t ** w.view(-1, 1, 1), dim=0)[:, 0]
