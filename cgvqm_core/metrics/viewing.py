"""The study's viewing condition: one setting that gives FLIP its pixels per degree and
ColorVideoVDP its display model.

Default: ColorVideoVDP's ``standard_4k`` (the CGVQM paper's 'standard-4K'): a 30-inch
3840x2160 display of 200 cd/m^2 peak luminance and contrast 1000:1 in a 250 lux office,
seen from 0.7472 m (twice the display height), which is 75.4 pixels per visual degree.
The geometry of the named displays below is the one ColorVideoVDP ships (a test checks that
both agree); ``ppd`` overrides the geometry for both metrics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import CGVQMError

#: name -> (horizontal pixels, vertical pixels, diagonal inches, viewing distance m)
DISPLAYS: dict[str, tuple[int, int, float, float]] = {
    "standard_4k": (3840, 2160, 30.0, 0.7472),
    "standard_fhd": (1920, 1080, 24.0, 0.6),
    "sdr_4k_30": (3840, 2160, 30.0, 0.6),
    "sdr_fhd_24": (1920, 1080, 24.0, 0.6),
}
DEFAULT_DISPLAY = "standard_4k"


def pixels_per_degree(width_px: int, height_px: int, diagonal_in: float,
                      distance_m: float) -> float:
    """Pixels per visual degree at the display's centre."""
    aspect = width_px / height_px
    height_m = math.sqrt((diagonal_in * 0.0254) ** 2 / (1 + aspect**2))
    pixel_m = aspect * height_m / width_px
    return 1.0 / (2 * math.degrees(math.atan(0.5 * pixel_m / distance_m)))


@dataclass(frozen=True)
class ViewingCondition:
    """A named display (ColorVideoVDP's display models) and, optionally, a fixed ppd."""

    display: str = DEFAULT_DISPLAY
    ppd: float | None = None

    def __post_init__(self) -> None:
        if self.display not in DISPLAYS:
            raise CGVQMError(f"unknown display {self.display!r}; choose one of "
                             f"{', '.join(DISPLAYS)} (or give --ppd)")
        if self.ppd is not None and not (self.ppd > 0 and math.isfinite(self.ppd)):
            raise CGVQMError(f"pixels per degree must be a positive number, got {self.ppd}")

    @property
    def pixels_per_degree(self) -> float:
        if self.ppd is not None:
            return float(self.ppd)
        return pixels_per_degree(*DISPLAYS[self.display])

    def to_dict(self) -> dict[str, object]:
        return {"display": self.display, "ppd": round(self.pixels_per_degree, 4)}
