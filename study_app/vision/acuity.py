"""Viewing geometry from a credit-card calibration, and optotypes drawn at a visual angle.

Geometry: the participant resizes an on-screen rectangle until it matches a real ID-1 card
(ISO/IEC 7810: 85.60 mm x 53.98 mm); its width in pixels gives pixels per millimetre, and
with the stated viewing distance ``D`` one degree of visual angle at the centre of the
screen spans ``2 D tan(0.5 deg)`` millimetres (at 57.3 cm, 10.0 mm).

Optotypes follow the usual convention (Snellen; ISO 8596 for the Landolt C): an optotype is
five stroke widths tall and its stroke (the Landolt C's gap, the E's bars) is the detail to
resolve, the minimum angle of resolution (MAR). 20/20 (6/6, logMAR 0.0) is a 1 arcmin
stroke, a 5 arcmin optotype; logMAR = log10(MAR / 1 arcmin). An optotype whose stroke
would be narrower than one pixel cannot be drawn faithfully on the display: it is refused
(:class:`OptotypeTooSmallError`) rather than drawn blurred.

Contrast is Weber contrast, (L_optotype - L_background) / L_background, in linear light on a
mid-grey background (sRGB code 188, the code nearest half the white luminance); ``contrast``
is its magnitude, dark optotypes by default; the codes shown are the nearest 8-bit ones
(:func:`grey_levels` says which contrast they really show). Luminance assumes an sRGB display.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np

from .dichromacy import linear_to_srgb, srgb_to_linear

ID1_WIDTH_MM = 85.60
ID1_HEIGHT_MM = 53.98
VIEWING_DISTANCE_CM = (30.0, 200.0)
# Pixel densities of real displays: 1.5 px/mm (38 ppi, a large TV up close) to 24 px/mm
# (610 ppi, the densest phones). A card outside this range was not matched to a real card.
PX_PER_MM = (1.5, 24.0)
STROKES = 5  # an optotype is five strokes tall
MIN_STROKE_PX = 1.0
BACKGROUND = 0.5  # linear luminance of the mid-grey background, of the display's white
SUPERSAMPLE = 8

OptotypeKind = Literal["landolt_c", "tumbling_e"]
OPTOTYPES: tuple[OptotypeKind, ...] = ("landolt_c", "tumbling_e")
Orientation = Literal["right", "up", "left", "down"]
ORIENTATIONS: tuple[Orientation, ...] = ("right", "up", "left", "down")
Polarity = Literal["dark", "light"]


@dataclass(frozen=True)
class Geometry:
    """How many pixels a millimetre and a degree of visual angle span on this display."""

    px_per_mm: float
    px_per_degree: float
    viewing_distance_cm: float

    @property
    def px_per_arcmin(self) -> float:
        return self.px_per_degree / 60

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


class OptotypeTooSmallError(ValueError):
    """The optotype's stroke would be under one pixel on this display."""

    def __init__(self, size_arcmin: float, smallest_arcmin: float) -> None:
        super().__init__(
            f"a {size_arcmin:.2f} arcmin optotype has strokes under {MIN_STROKE_PX:g} px on "
            f"this display; the smallest it can draw is {smallest_arcmin:.2f} arcmin "
            f"(logMAR {logmar(smallest_arcmin):.2f}): sit further away or use a denser display")
        self.size_arcmin = size_arcmin
        self.smallest_arcmin = smallest_arcmin


class ContrastTooLowError(ValueError):
    """The contrast is below what 8-bit sRGB codes can show on the mid-grey background."""


def from_code(code: int) -> float:
    """The linear luminance (of the display's white) of an 8-bit sRGB grey code."""
    return float(srgb_to_linear(code / 255))


def card_rect_px(card_width_px: float) -> tuple[int, int]:
    """The on-screen card's (width, height) in pixels, with the ID-1 aspect ratio (square
    pixels assumed), for drawing the rectangle the participant resizes."""
    return round(card_width_px), round(card_width_px * ID1_HEIGHT_MM / ID1_WIDTH_MM)


def card_calibration(card_width_px: float, viewing_distance_cm: float) -> Geometry:
    """The geometry from the matched card's width in pixels and the viewing distance."""
    for name, value in (("card width", card_width_px),
                        ("viewing distance", viewing_distance_cm)):
        if not math.isfinite(value) or value <= 0:
            raise ValueError(f"the {name} must be a positive number, got {value!r}")
    lo, hi = VIEWING_DISTANCE_CM
    if not lo <= viewing_distance_cm <= hi:
        raise ValueError(f"a viewing distance of {viewing_distance_cm:g} cm is outside "
                         f"{lo:g}..{hi:g} cm: measure from the eyes to the screen")
    px_per_mm = card_width_px / ID1_WIDTH_MM
    lo, hi = PX_PER_MM
    if not lo <= px_per_mm <= hi:
        raise ValueError(
            f"a card {card_width_px:g} px wide means {px_per_mm:.2f} px/mm, which no display "
            f"has (plausible: {lo:g}..{hi:g} px/mm, a card {lo * ID1_WIDTH_MM:.0f}.."
            f"{hi * ID1_WIDTH_MM:.0f} px wide): match the rectangle to a real bank card")
    mm_per_degree = 2 * viewing_distance_cm * 10 * math.tan(math.radians(0.5))
    return Geometry(px_per_mm, px_per_mm * mm_per_degree, float(viewing_distance_cm))


def logmar(size_arcmin: float) -> float:
    """logMAR of an optotype ``size_arcmin`` tall (its stroke is a fifth of that)."""
    return math.log10(size_arcmin / STROKES)


def size_arcmin(logmar_value: float) -> float:
    """The optotype height in arcmin for a logMAR (0.0: 5 arcmin, 20/20)."""
    return STROKES * 10**logmar_value


def snellen(size_arcmin_value: float, distance: int = 20) -> str:
    """The Snellen fraction, e.g. ``20/40`` for a 10 arcmin optotype."""
    return f"{distance}/{distance * size_arcmin_value / STROKES:.0f}"


def smallest_size_arcmin(geometry: Geometry) -> float:
    """The smallest optotype this display can draw: strokes of ``MIN_STROKE_PX``."""
    return STROKES * MIN_STROKE_PX / geometry.px_per_arcmin


def grey_levels(contrast: float, polarity: Polarity = "dark") -> tuple[int, int, float]:
    """(background code, optotype code, Weber contrast the codes really show) in 8-bit
    sRGB; :class:`ContrastTooLowError` when the two codes would be equal."""
    if not 0 < contrast <= 1:
        raise ValueError(f"Weber contrast must be in (0, 1], got {contrast!r}")
    bg = background_code()
    lb = from_code(bg)
    fg = round(float(linear_to_srgb(lb * (1 - contrast if polarity == "dark" else 1 + contrast)))
               * 255)
    if bg == fg:
        raise ContrastTooLowError(f"a Weber contrast of {contrast:g} is below one 8-bit step "
                                  f"on the mid-grey background")
    lf = from_code(fg)
    return bg, fg, abs(lf - lb) / lb


def _canonical(u: np.ndarray, v: np.ndarray, orientation: Orientation) -> tuple[np.ndarray,
                                                                                  np.ndarray]:
    """Rotate coordinates (y down) so that the opening faces right."""
    if orientation == "right":
        return u, v
    if orientation == "up":
        return -v, u
    if orientation == "left":
        return -u, -v
    return v, -u


def _inside(kind: OptotypeKind, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The optotype, opening to the right, in stroke units about its centre."""
    if kind == "landolt_c":  # ISO 8596: outer diameter 5, inner 3, gap 1
        r = np.hypot(u, v)
        return (r >= 1.5) & (r <= 2.5) & ~((u > 0) & (np.abs(v) < 0.5))
    box = (np.abs(u) <= 2.5) & (np.abs(v) <= 2.5)  # E: 5 x 5, three bars and a spine
    return box & ((u <= -1.5) | (np.abs(v) >= 1.5) | (np.abs(v) <= 0.5))


def optotype(kind: OptotypeKind, orientation: Orientation, size_arcmin_value: float,
             contrast: float, geometry: Geometry, *, polarity: Polarity = "dark",
             margin: float = 0.5) -> np.ndarray:
    """A square uint8 greyscale image (sRGB codes): the optotype, ``size_arcmin_value`` tall,
    opening towards ``orientation``, centred on mid-grey with ``margin`` optotype heights
    around it. Edges are anti-aliased in linear light (``SUPERSAMPLE``^2 samples a pixel)."""
    if kind not in OPTOTYPES:
        raise ValueError(f"optotype {kind!r} is not one of {', '.join(OPTOTYPES)}")
    if orientation not in ORIENTATIONS:
        raise ValueError(f"orientation {orientation!r} is not one of {', '.join(ORIENTATIONS)}")
    smallest = smallest_size_arcmin(geometry)
    if size_arcmin_value < smallest:
        raise OptotypeTooSmallError(size_arcmin_value, smallest)
    bg, fg, _ = grey_levels(contrast, polarity)
    stroke = size_arcmin_value * geometry.px_per_arcmin / STROKES
    side = math.ceil(STROKES * stroke * (1 + 2 * margin) - 0.01)  # no pixel for a 1 % sliver
    n = side * SUPERSAMPLE
    coords = ((np.arange(n) + 0.5) / SUPERSAMPLE - side / 2) / stroke
    u, v = _canonical(coords[None, :], coords[:, None], orientation)
    cover = _inside(kind, u, v).reshape(side, SUPERSAMPLE, side, SUPERSAMPLE).mean(axis=(1, 3))
    lb, lf = from_code(bg), from_code(fg)
    return np.round(linear_to_srgb(lb + (lf - lb) * cover) * 255).astype(np.uint8)


def background_code() -> int:
    """The 8-bit sRGB code of the mid-grey background, for filling the screen around."""
    return round(float(linear_to_srgb(BACKGROUND)) * 255)
