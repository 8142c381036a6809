"""Variable-rate shading: coarse shading in low-contrast tiles under a shading budget.

The frame is cut into tiles; each tile is shaded at full rate, once per 2x2 block, or once
per 4x4 block. The rates come from the previous frame's contrast (as real VRS drivers use the
last frame), coarsening the lowest-contrast tiles first until the cost (shading invocations
relative to full rate) fits the budget. A coarse block gets the average of its full-rate
shading, so its pixels are identical.
"""

from __future__ import annotations

import numpy as np

from .color import luminance, srgb_encode, tonemap

TILE = 8
RATE_COST = {1: 1.0, 2: 0.25, 4: 1.0 / 16.0}


def tile_contrast(linear: np.ndarray, tile: int = TILE) -> np.ndarray:
    """Max minus min display luminance per tile, (H/tile, W/tile)."""
    lum = srgb_encode(tonemap(luminance(linear)))
    h, w = lum.shape
    t = lum.reshape(h // tile, tile, w // tile, tile)
    return t.max(axis=(1, 3)) - t.min(axis=(1, 3))


def assign_rates(contrast: np.ndarray, budget: float) -> np.ndarray:
    """Block size per tile (1, 2 or 4) so that the mean cost is at most ``budget``.

    Tiles are coarsened in order of increasing contrast: first to 2x2, and when every tile
    is 2x2 and the budget is still exceeded, on to 4x4 in the same order.
    """
    order = np.argsort(contrast, axis=None, kind="stable")
    n = order.size
    rates = np.ones(n, dtype=np.int64)
    cost = 1.0

    def coarsen(to: int, frm: int) -> bool:
        nonlocal cost
        step = (RATE_COST[frm] - RATE_COST[to]) / n
        for idx in order:
            if cost <= budget + 1e-12:
                return True
            rates[idx] = to
            cost -= step
        return cost <= budget + 1e-12

    if not coarsen(2, 1):
        coarsen(4, 2)
    return rates.reshape(contrast.shape)


def coarse_shade(linear: np.ndarray, rates: np.ndarray, tile: int = TILE) -> np.ndarray:
    """Replace each b x b block of a tile with rate b by the block's mean."""
    out = linear.copy()
    h, w = linear.shape[:2]
    for b in (2, 4):
        block_mean = linear.reshape(h // b, b, w // b, b, 3).mean(axis=(1, 3))
        coarse = np.repeat(np.repeat(block_mean, b, axis=0), b, axis=1)
        mask = np.repeat(np.repeat(rates == b, tile, axis=0), tile, axis=1)
        out[mask] = coarse[mask]
    return out


def vrs_sequence(refs: list[np.ndarray], budget: float, tile: int = TILE) -> list[np.ndarray]:
    """Coarse-shaded frames; frame i uses the contrast of reference frame i-1."""
    h, w = refs[0].shape[:2]
    ph, pw = -h % tile, -w % tile
    out = []
    for i, ref in enumerate(refs):
        prev = refs[max(i - 1, 0)]
        padded = np.pad(ref, ((0, ph), (0, pw), (0, 0)), mode="edge")
        rates = assign_rates(tile_contrast(np.pad(prev, ((0, ph), (0, pw), (0, 0)),
                                                  mode="edge"), tile), budget)
        out.append(coarse_shade(padded, rates, tile)[:h, :w])
    return out
