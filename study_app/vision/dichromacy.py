"""Colour arithmetic for the colour-vision plates: sRGB to linear RGB to CIELAB, and how a
dichromat sees a colour.

Dichromacy is simulated with the matrices of Machado, Oliveira and Fernandes (2009, "A
physiologically-based model for simulation of color vision deficiency", IEEE TVCG 15(6)) at
severity 1.0, which act on linear sRGB. For protanopia and deuteranopia they are of rank two:
colours that differ along their null direction look the same to that dichromat (a confusion
line). Their tritanopia matrix is not singular; along its weakest direction a difference keeps
about 12 % of its size (the smallest singular value 0.156 over the largest 1.33). Colour
differences are CIE76 Delta E in CIELAB (D65 white), enough to tell "clearly different" from
"the same" in a test.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

Deficiency = Literal["protan", "deutan", "tritan"]
DEFICIENCIES: tuple[Deficiency, ...] = ("protan", "deutan", "tritan")

MACHADO_2009: dict[str, np.ndarray] = {
    "protan": np.array([[0.152286, 1.052583, -0.204868],
                        [0.114503, 0.786281, 0.099216],
                        [-0.003882, -0.048116, 1.051998]]),
    "deutan": np.array([[0.367322, 0.860646, -0.227968],
                        [0.280085, 0.672501, 0.047413],
                        [-0.011820, 0.042940, 0.968881]]),
    "tritan": np.array([[1.255528, -0.076749, -0.178779],
                        [-0.078411, 0.930809, 0.147602],
                        [0.004733, 0.691367, 0.303900]]),
}
# linear sRGB (D65) to CIE XYZ (IEC 61966-2-1)
SRGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                        [0.2126729, 0.7151522, 0.0721750],
                        [0.0193339, 0.1191920, 0.9503041]])
D65_WHITE = SRGB_TO_XYZ @ np.ones(3)


def srgb_to_linear(srgb: np.ndarray) -> np.ndarray:
    """sRGB in 0..1 to linear light (the IEC 61966-2-1 curve)."""
    c = np.asarray(srgb, dtype=float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    c = np.clip(np.asarray(linear, dtype=float), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def simulate(linear: np.ndarray, deficiency: Deficiency) -> np.ndarray:
    """Linear RGB (..., 3) as the dichromat sees it (Machado 2009, severity 1)."""
    return np.asarray(linear, dtype=float) @ MACHADO_2009[deficiency].T


def confusion_direction(deficiency: Deficiency) -> np.ndarray:
    """The unit direction in linear RGB along which ``deficiency`` sees the least change
    (the null direction of its simulation matrix)."""
    _, _, vt = np.linalg.svd(MACHADO_2009[deficiency])
    d = vt[-1]
    return d / np.linalg.norm(d) * (1 if d[np.argmax(np.abs(d))] > 0 else -1)


def lab(linear: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of linear sRGB colours (..., 3)."""
    xyz = np.asarray(linear, dtype=float) @ SRGB_TO_XYZ.T / D65_WHITE
    e = 216 / 24389
    f = np.where(xyz > e, np.cbrt(xyz), (24389 / 27 * xyz + 16) / 116)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]),
                     200 * (f[..., 1] - f[..., 2])], axis=-1)


def delta_e(a_linear: np.ndarray, b_linear: np.ndarray) -> np.ndarray:
    """CIE76 colour difference between linear sRGB colours."""
    return np.linalg.norm(lab(a_linear) - lab(b_linear), axis=-1)
