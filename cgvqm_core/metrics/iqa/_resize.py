"""MATLAB-style bicubic resizing (imresize): Keys cubic a = -0.5, antialiased when shrinking,
symmetric padding at the borders. Used by SR-SIM, whose saliency is computed at 1/4 size."""

from __future__ import annotations

import math

import numpy as np
import torch


def _cubic(x: np.ndarray, a: float = -0.5) -> np.ndarray:
    ax = np.abs(x)
    ax2, ax3 = ax * ax, ax * ax * ax
    near = ((a + 2) * ax3 - (a + 3) * ax2 + 1) * (ax <= 1)
    far = (a * ax3 - 5 * a * ax2 + 8 * a * ax - 4 * a) * ((ax > 1) & (ax <= 2))
    return near + far


def resize_matrix(n_in: int, n_out: int, scale: float) -> np.ndarray:
    """(n_out, n_in) matrix of one axis' resampling weights."""
    shrink = scale < 1
    taps = (math.ceil(4 / scale) if shrink else 4) + 2
    factor = scale if shrink else 1.0
    pos = (np.arange(n_out, dtype=np.float64) + 0.5) / scale - 0.5
    base = np.floor(pos) - taps // 2 + 1
    offsets = np.arange(taps)
    w = _cubic((pos[:, None] - (base[:, None] + offsets[None, :])) * factor)
    w /= w.sum(1, keepdims=True)
    idx = (base[:, None] + offsets[None, :]).astype(np.int64)
    # symmetric padding: -1 -> 0, -2 -> 1, n -> n - 1, n + 1 -> n - 2
    period = 2 * n_in
    idx = np.mod(idx, period)
    idx = np.where(idx >= n_in, period - 1 - idx, idx)
    m = np.zeros((n_out, n_in))
    np.add.at(m, (np.repeat(np.arange(n_out), taps), idx.ravel()), w.ravel())
    return m


def imresize(x: torch.Tensor, *, scale: float | None = None,
             size: tuple[int, int] | None = None) -> torch.Tensor:
    """Resize (B, C, H, W) by ``scale`` (output ceil(H * scale)) or to ``size``."""
    h, w = x.shape[-2:]
    if size is None:
        assert scale is not None
        size, scales = (math.ceil(h * scale), math.ceil(w * scale)), (scale, scale)
    else:
        scales = (size[0] / h, size[1] / w)
    out = x
    if scales[0] != 1:
        mh = torch.from_numpy(resize_matrix(h, size[0], scales[0])).to(x.dtype).to(x.device)
        out = torch.einsum("oh,bchw->bcow", mh, out)
    if scales[1] != 1:
        mw = torch.from_numpy(resize_matrix(w, size[1], scales[1])).to(x.dtype).to(x.device)
        out = torch.einsum("ow,bchw->bcho", mw, out)
    return out
