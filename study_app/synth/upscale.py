"""Temporal anti-aliased upscaling (TAAU) of jittered low-resolution renders.

Each output frame takes the current low-resolution frame, resampled to the output grid at the
positions its jittered samples really had, and blends it into the history, which is
reprojected with the renderer's motion vectors and clamped to the current neighbourhood (so
stale colours are limited). What is left are the family's artefacts: blur, ghosting behind
moving edges and flicker on sub-pixel detail.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def halton(index: int, base: int) -> float:
    """Element ``index`` (from 1) of the van der Corput sequence in ``base``."""
    f, r = 1.0, 0.0
    while index > 0:
        f /= base
        r += f * (index % base)
        index //= base
    return r


def jitter_sequence(n: int, period: int = 8) -> list[tuple[float, float]]:
    """Sub-pixel offsets in (-0.5, 0.5), Halton (2, 3) repeated every ``period`` frames."""
    return [(halton(i % period + 1, 2) - 0.5, halton(i % period + 1, 3) - 0.5) for i in range(n)]


def _sample(img: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear samples of (h, w, c) ``img`` at fractional pixel indices (edge clamped)."""
    coords = np.stack([rows, cols])
    return np.stack(
        [ndimage.map_coordinates(img[..., c], coords, order=1, mode="nearest")
         for c in range(img.shape[-1])],
        axis=-1,
    )


class TemporalUpscaler:
    """Feed low-resolution frames in order; each call returns the full-resolution frame."""

    def __init__(self, width: int, height: int, *, blend: float = 0.1) -> None:
        self.width, self.height = width, height
        self.blend = blend
        self.history: np.ndarray | None = None
        yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
        self._yc, self._xc = yy + 0.5, xx + 0.5  # output pixel centres

    def step(self, low: np.ndarray, motion_low: np.ndarray,
             jitter: tuple[float, float]) -> np.ndarray:
        """``low`` (h, w, 3) rendered with sample offset ``jitter`` (image axes, pixels)."""
        h, w = low.shape[:2]
        sx, sy = w / self.width, h / self.height
        # a low-res sample with index j sits at j + 0.5 + jitter (low-res pixel units)
        rows = self._yc * sy - 0.5 - jitter[1]
        cols = self._xc * sx - 0.5 - jitter[0]
        current = _sample(low, rows, cols)
        if self.history is None:
            self.history = current
            return current
        motion = _sample(motion_low, self._yc * sy - 0.5, self._xc * sx - 0.5)
        prev_x = self._xc + motion[..., 0] / sx
        prev_y = self._yc + motion[..., 1] / sy
        history = _sample(self.history, prev_y - 0.5, prev_x - 0.5)
        lo = ndimage.minimum_filter(current, size=(3, 3, 1), mode="nearest")
        hi = ndimage.maximum_filter(current, size=(3, 3, 1), mode="nearest")
        history = np.clip(history, lo, hi)
        offscreen = (prev_x < 0) | (prev_x > self.width) | (prev_y < 0) | (prev_y > self.height)
        out = self.blend * current + (1.0 - self.blend) * history
        out = np.where(offscreen[..., None], current, out).astype(np.float32)
        self.history = out
        return out
