"""Linear HDR radiance -> 8-bit sRGB display values (the only place stimuli are quantised)."""

from __future__ import annotations

import numpy as np


def tonemap(linear: np.ndarray) -> np.ndarray:
    """Exponential tone curve 1 - exp(-x): keeps fireflies and lights bright but bounded."""
    return -np.expm1(-np.maximum(linear, 0.0))


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """The sRGB opto-electronic transfer function on [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def to_display(linear: np.ndarray) -> np.ndarray:
    """(…, 3) linear radiance -> uint8 sRGB after tone mapping."""
    encoded = srgb_encode(tonemap(np.asarray(linear, dtype=np.float32)))
    return np.rint(encoded * 255.0).astype(np.uint8)


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of the last axis."""
    return rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722
