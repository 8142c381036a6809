"""The display's refresh rate, measured from the times of vsync'd buffer flips (pure).

With vsync each flip returns at a display refresh, so flip intervals are whole multiples of
the refresh period: one period normally, two or more where a flip missed a refresh (dropped).
:func:`estimate_refresh` fits the period to those multiples, so a few dropped flips do not
bias it, and tells apart: no vsync at all (flips return at once), a steady display, and one
whose intervals do not sit on multiples of one period (variable refresh rate, or an
overloaded computer).
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

# No monitor on sale refreshes faster than 600 Hz: a median flip interval shorter than this
# means the driver did not wait for the display.
MIN_VSYNC_INTERVAL_S = 1 / 600
# Faster than 250 Hz (360-540 Hz gaming monitors), flips that return as soon as a frame is
# drawn could pass for a refresh; such flips are only believed when they are as steady as a
# display's: relative jitter below this, and no more off-grid intervals than a steady one.
FAST_REFRESH_S = 1 / 250
FAST_MAX_JITTER = 0.03
# An interval whose ratio to the fitted period is further than this from a whole number does
# not belong to a fixed refresh rate.
OFF_GRID_TOLERANCE = 0.15
# More than this share of off-grid intervals: the refresh is variable (or the machine busy).
MAX_OFF_GRID_SHARE = 0.10
MIN_FLIPS = 20


@dataclass(frozen=True)
class RefreshEstimate:
    """What the flip times say about the display."""

    n_intervals: int
    vsync: bool
    hz: float
    period_s: float
    jitter: float
    """Relative standard deviation of the on-grid intervals, each divided by its refreshes."""
    dropped: int
    """Intervals that spanned more than one refresh."""
    off_grid: int
    """Intervals that are no whole multiple of the period (variable refresh, stalls)."""

    @property
    def variable(self) -> bool:
        return self.vsync and self.off_grid > MAX_OFF_GRID_SHARE * self.n_intervals

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["variable"] = self.variable
        d["hz"] = round(self.hz, 3)
        d["period_s"] = round(self.period_s, 7)
        d["jitter"] = round(self.jitter, 5)
        return d


def estimate_refresh(flip_times: Sequence[float]) -> RefreshEstimate:
    """Estimate the refresh rate from monotonic flip timestamps (seconds).

    Raises ValueError with fewer than :data:`MIN_FLIPS` timestamps or when time goes back.
    """
    times = [float(t) for t in flip_times]
    if len(times) < MIN_FLIPS:
        raise ValueError(f"need at least {MIN_FLIPS} flip times, got {len(times)}")
    intervals = [b - a for a, b in itertools.pairwise(times)]
    if min(intervals) < 0:
        raise ValueError("flip times must not decrease")
    n = len(intervals)
    median = statistics.median(intervals)
    if median < MIN_VSYNC_INTERVAL_S:
        return RefreshEstimate(n, False, 0.0, 0.0, 0.0, 0, 0)
    # A first guess of the period from the shorter intervals (dropped flips are longer), then
    # a least-squares fit of period * k_i to the intervals that sit on the grid.
    period = statistics.median(sorted(intervals)[: max(1, n // 2)])
    on_grid: list[tuple[float, int]] = []
    for _ in range(3):
        on_grid = []
        for iv in intervals:
            k = max(1, round(iv / period))
            if abs(iv / period - k) <= OFF_GRID_TOLERANCE * (1 if k == 1 else 1.5):
                on_grid.append((iv, k))
        if not on_grid:
            break
        period = sum(iv * k for iv, k in on_grid) / sum(k * k for _, k in on_grid)
    off_grid = n - len(on_grid)
    dropped = sum(1 for _, k in on_grid if k > 1)
    per_refresh = [iv / k for iv, k in on_grid]
    jitter = (statistics.pstdev(per_refresh) / period) if len(per_refresh) > 1 else 0.0
    if median < FAST_REFRESH_S and (not on_grid or jitter > FAST_MAX_JITTER
                                    or off_grid > MAX_OFF_GRID_SHARE * n):
        return RefreshEstimate(n, False, 0.0, 0.0, 0.0, 0, 0)
    return RefreshEstimate(n, True, 1.0 / period, period, jitter, dropped, off_grid)
