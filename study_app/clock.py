"""The presentation clock: one refresh counter shared by reference and test.

The frame shown at refresh ``n`` is ``floor(n * fps / refresh_hz) mod frame_count`` (computed
in exact rational arithmetic), the same index whichever video is showing, so switching shows
the co-located frame. Where vsync is missing, :class:`FlipPacer` paces flips on the monotonic
clock at the nominal refresh rate instead. :class:`FlipStats` measures every flip: an interval
over 1.5x the nominal period is a dropped frame.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from fractions import Fraction

DROP_FACTOR = 1.5


def _rational(x: float) -> Fraction:
    return Fraction(x).limit_denominator(1001)


def frame_index(refresh: int, fps: float, refresh_hz: float, frame_count: int,
                *, loop: bool = True) -> int:
    """Video frame to show at refresh number ``refresh`` (0-based)."""
    if frame_count < 1:
        raise ValueError("frame_count must be at least 1")
    step = _rational(fps) / _rational(refresh_hz)
    index = math.floor(refresh * step)
    return index % frame_count if loop else min(index, frame_count - 1)


def blank_refreshes(seconds: float, refresh_hz: float) -> int:
    """Number of refreshes of a blank of ``seconds`` (rounded to the nearest refresh)."""
    return round(seconds * refresh_hz)


def refreshes_elapsed(interval_s: float, period_s: float) -> int:
    """Refreshes that passed during one flip interval (at least one)."""
    return max(1, round(interval_s / period_s))


@dataclass
class FlipStats:
    """Flip timestamps of one trial and what they say about presentation quality.

    :meth:`break_chain` marks a gap that is not a presentation interval (the participant left
    the videos for the rating screen), so the next flip starts a new run of intervals.
    """

    period_s: float
    times: list[float] = field(default_factory=list)
    intervals: list[float] = field(default_factory=list)
    _chained: bool = field(default=False, repr=False)

    def add(self, t: float) -> float | None:
        """Record a flip at monotonic time ``t``; returns the interval since the last one."""
        interval = t - self.times[-1] if self.times and self._chained else None
        self.times.append(t)
        if interval is not None:
            self.intervals.append(interval)
        self._chained = True
        return interval

    def break_chain(self) -> None:
        self._chained = False

    @property
    def frames_presented(self) -> int:
        return len(self.times)

    @property
    def dropped_frames(self) -> int:
        limit = DROP_FACTOR * self.period_s
        return sum(1 for d in self.intervals if d > limit)

    @property
    def missed_refreshes(self) -> int:
        """Refreshes that passed without a new frame: a late flip of ``k`` periods missed
        ``k - 1`` of them. One long stall (a 1 s freeze at 60 Hz misses 59) counts as one
        dropped frame above, which is what re-queueing must not judge by."""
        return sum(self.missed_by(d) for d in self.intervals)

    def missed_by(self, interval: float) -> int:
        """Refreshes one flip interval hid: 0 on time, else at least 1."""
        if interval <= DROP_FACTOR * self.period_s:
            return 0
        return max(1, round(interval / self.period_s) - 1)

    @property
    def max_interval_ms(self) -> float:
        return 1000.0 * max(self.intervals, default=0.0)

    def percentile_interval_ms(self, q: float) -> float:
        iv = sorted(self.intervals)
        if not iv:
            return 0.0
        k = min(len(iv) - 1, max(0, math.ceil(q / 100.0 * len(iv)) - 1))
        return 1000.0 * iv[k]


class FlipPacer:
    """Flip deadlines on the monotonic clock when the driver gives no vsync.

    ``wait()`` returns when the next refresh slot begins; when the caller fell behind by more
    than a slot, the schedule re-anchors (those slots count as dropped through FlipStats).
    """

    def __init__(self, refresh_hz: float, *, clock: Callable[[], float] = time.perf_counter,
                 sleep: Callable[[float], None] = time.sleep, spin_s: float = 0.0015) -> None:
        self.period = 1.0 / refresh_hz
        self._clock = clock
        self._sleep = sleep
        self._spin = spin_s
        self._next: float | None = None

    def wait(self) -> float:
        """Block until the next flip slot; returns the slot's time."""
        now = self._clock()
        if self._next is None:
            self._next = now
        elif now - self._next > self.period:
            # Too late for this slot: skip to the next slot after now.
            missed = math.ceil((now - self._next) / self.period)
            self._next += missed * self.period
        remaining = self._next - self._clock()
        if remaining > self._spin:
            self._sleep(remaining - self._spin)
        while self._clock() < self._next:
            pass
        slot = self._next
        self._next += self.period
        return slot

    def reset(self) -> None:
        self._next = None
