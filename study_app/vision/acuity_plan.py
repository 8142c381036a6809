"""The contrast/acuity check's trials: which optotype, how large, how faint, which way.

Two descending series by the method of constant stimuli, four alternatives each (guessing
is right a quarter of the time):

- **acuity**: high-contrast optotypes (Weber 0.9) from logMAR 1.0 (20/200) down to 0.0
  (20/20) in the usual 0.1-0.2 steps;
- **contrast**: optotypes of one comfortable size (logMAR 0.8, a gap of about 6 arcmin, near
  the peak of contrast sensitivity) from Weber contrast 0.5 down to 0.032, a factor of two a
  level (log contrast sensitivity 0.3 to 1.5, as on a Pelli-Robson chart in whole triplets).

Every level is planned with ``trials_per_level`` orientations drawn from the seed; a screen
stops a level once it is decided and a series after its first failed level
(:func:`.acuity_scoring.level_outcome`). Levels this display cannot draw (strokes under a
pixel at the measured geometry, optotypes taller than the window has room for, or a contrast
8-bit codes cannot show) are left out and listed, never drawn blurred, cropped or rounded to
another contrast.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

from .acuity import (
    ORIENTATIONS,
    ContrastTooLowError,
    Geometry,
    OptotypeKind,
    Orientation,
    grey_levels,
    size_arcmin,
    smallest_size_arcmin,
)

Series = Literal["acuity", "contrast"]
LOGMAR_LEVELS = (1.0, 0.8, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0)  # 20/200 .. 20/20
HIGH_CONTRAST = 0.9  # Weber, dark on the mid-grey background
CONTRAST_LEVELS = (0.5, 0.25, 0.125, 0.063, 0.032)  # Weber; log CS 0.3 .. 1.5
CONTRAST_LOGMAR = 0.8  # 31.5 arcmin optotypes with a 6.3 arcmin gap (about 5 cycles/degree)
TRIALS_PER_LEVEL = 5


@dataclass(frozen=True)
class OptotypeTrial:
    """One optotype to show; ``orientation`` is the right answer."""

    series: Series
    level: int  # 0 = the easiest level of its series
    logmar: float
    size_arcmin: float
    contrast: float
    kind: OptotypeKind
    orientation: Orientation

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class AcuityPlan:
    """The planned trials of both series, and the levels left out on this display."""

    trials: list[OptotypeTrial]
    undrawable_logmar: list[float] = field(default_factory=list)  # strokes under a pixel
    unshowable_contrast: list[float] = field(default_factory=list)
    too_large_logmar: list[float] = field(default_factory=list)  # taller than the window's room

    def series(self, name: Series) -> list[OptotypeTrial]:
        return [t for t in self.trials if t.series == name]

    def levels(self, name: Series) -> list[list[OptotypeTrial]]:
        """The trials of one series grouped by level, easiest first."""
        out: list[list[OptotypeTrial]] = []
        for t in self.series(name):
            if not out or out[-1][0].level != t.level:
                out.append([])
            out[-1].append(t)
        return out


def drawable_levels(geometry: Geometry, levels: tuple[float, ...] = LOGMAR_LEVELS, *,
                    max_size_px: float | None = None) -> tuple[list[float], list[float]]:
    """(logMAR levels this display can draw, levels too small for it), largest first.
    Levels taller than ``max_size_px`` (the room the window has) are left out of both."""
    smallest = smallest_size_arcmin(geometry)
    ordered = [lv for lv in sorted(levels, reverse=True)
               if max_size_px is None or size_arcmin(lv) * geometry.px_per_arcmin <= max_size_px]
    return ([lv for lv in ordered if size_arcmin(lv) >= smallest],
            [lv for lv in ordered if size_arcmin(lv) < smallest])


def too_large_levels(geometry: Geometry, levels: tuple[float, ...] = LOGMAR_LEVELS, *,
                     max_size_px: float | None = None) -> list[float]:
    """The logMAR levels taller than ``max_size_px`` at this geometry, largest first: left
    out of the plan like the levels too small, and listed apart (their cause is the window)."""
    if max_size_px is None:
        return []
    return [lv for lv in sorted(levels, reverse=True)
            if size_arcmin(lv) * geometry.px_per_arcmin > max_size_px]


def _no_plan_reason(geometry: Geometry, logmar: float, max_size_px: float | None) -> str:
    """Why the largest optotype of a series cannot be drawn, by its cause."""
    need = size_arcmin(logmar) * geometry.px_per_arcmin
    if max_size_px is not None and need > max_size_px:
        return (f"this window is too small for the check's optotypes: it cannot draw logMAR "
                f"{logmar:g} ({need:.0f} px tall at this geometry) in the {max_size_px:.0f} px "
                "it has room for; use a larger window or full screen")
    return ("this display cannot draw the check's largest optotypes at this distance "
            "(their strokes would be under a pixel)")


def showable_contrasts(levels: tuple[float, ...] = CONTRAST_LEVELS
                       ) -> tuple[list[float], list[float]]:
    """(contrasts 8-bit codes can show on the background, those they cannot), highest
    first."""
    shown, not_shown = [], []
    for c in sorted(levels, reverse=True):
        try:
            grey_levels(c)
            shown.append(c)
        except ContrastTooLowError:
            not_shown.append(c)
    return shown, not_shown


def acuity_plan(geometry: Geometry, seed: int, *, kind: OptotypeKind = "landolt_c",
                trials_per_level: int = TRIALS_PER_LEVEL,
                logmar_levels: tuple[float, ...] = LOGMAR_LEVELS,
                contrast_levels: tuple[float, ...] = CONTRAST_LEVELS,
                contrast_logmar: float = CONTRAST_LOGMAR,
                max_size_px: float | None = None) -> AcuityPlan:
    """Both series for this display; the same seed gives the same orientations. ValueError
    when the display cannot draw the largest optotype of either series. ``max_size_px``: the
    tallest optotype the window has room for (larger levels are left out)."""
    if trials_per_level < 1:
        raise ValueError("each level needs at least one trial")
    sizes, too_small = drawable_levels(geometry, logmar_levels, max_size_px=max_size_px)
    too_large = too_large_levels(geometry, logmar_levels, max_size_px=max_size_px)
    contrast_drawn, _ = drawable_levels(geometry, (contrast_logmar,), max_size_px=max_size_px)
    if not sizes:
        raise ValueError(_no_plan_reason(geometry, min(logmar_levels), max_size_px))
    if not contrast_drawn:
        raise ValueError(_no_plan_reason(geometry, contrast_logmar, max_size_px))
    contrasts, too_faint = showable_contrasts(contrast_levels)
    rng = np.random.default_rng(seed)

    def way() -> Orientation:
        return ORIENTATIONS[int(rng.integers(len(ORIENTATIONS)))]

    trials = [OptotypeTrial("acuity", i, lv, size_arcmin(lv), HIGH_CONTRAST, kind, way())
              for i, lv in enumerate(sizes) for _ in range(trials_per_level)]
    trials += [OptotypeTrial("contrast", i, contrast_logmar, size_arcmin(contrast_logmar), c,
                             kind, way())
               for i, c in enumerate(contrasts) for _ in range(trials_per_level)]
    return AcuityPlan(trials, too_small, too_faint, too_large)
