"""One trial as a pure state machine: commands and flip times in, state and actions out.

The app turns input events into :class:`Command` objects (keys of any layout, clicks on the
slider or a button) and reports each buffer flip's time; the machine decides what the next
refresh shows (test, reference or the blank, and which video frame), when the rating screen
opens, and what the trial measured. No display, clock or file is touched here, so the whole
presentation logic is unit-tested with synthetic flip times.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from session_store import TrialResult, utc_now

from .clock import FlipStats, blank_refreshes, frame_index, refreshes_elapsed
from .slider import Slider

VIEW, RATE = "view", "rate"
NOTICE_SECONDS = 2.0


@dataclass(frozen=True)
class Command:
    """What the participant asked for.

    ``switch`` (test <-> reference), ``rate`` (open the rating screen), ``back`` (to the
    videos), ``pause``, ``submit``, ``step`` (slider by keys: ``direction`` +-1, ``coarse``),
    ``press``/``drag``/``release`` (slider by mouse at ``x``, ``y``).
    """

    name: str
    x: float = 0.0
    y: float = 0.0
    direction: int = 0
    coarse: bool = False


@dataclass(frozen=True)
class Action:
    """What the app must do: ``log`` (a state line), ``pause``, ``rating_opened``,
    ``viewing_resumed``, ``notice`` or ``submitted`` (``result`` holds the TrialResult)."""

    name: str
    info: dict[str, Any] = field(default_factory=dict)
    result: TrialResult | None = None


@dataclass
class TrialMachine:
    """The state of one trial on screen."""

    fps: float
    refresh_hz: float
    frames: int
    slider: Slider
    blank_seconds: float = 0.5
    loop: bool = True
    min_view_s: float | None = None
    vsync: bool = True
    details: dict[str, Any] = field(default_factory=dict)
    cpu_clock: Callable[[], float] = time.process_time
    wall_clock: Callable[[], str] = utc_now

    phase: str = VIEW
    showing: str = "test"
    n: int = 0
    blank_until: int | None = None
    blank_target: str | None = None
    n_toggles: int = 0
    notice_until: float = -1.0
    t_start: float | None = None
    presented_at: str | None = None

    def __post_init__(self) -> None:
        self.period = 1.0 / self.refresh_hz
        self.loop_s = self.frames / self.fps
        if self.min_view_s is None:
            self.min_view_s = self.loop_s
        self.blank_n = blank_refreshes(self.blank_seconds, self.refresh_hz)
        self.stats = FlipStats(self.period)
        self._switch_key_t: float | None = None
        self._blank_started_t: float | None = None
        self._blank_started_n = 0
        self.switch_latencies_ms: list[float] = []
        self.blank_durations_ms: list[float] = []
        self.blank_refresh_counts: list[int] = []
        self.toggle_times_ms: list[float] = []
        self.ms_on = {"test": 0.0, "reference": 0.0}
        self.viewing_s = 0.0
        self.flips = 0
        self._cpu_start = 0.0
        self._last_content: str | None = None
        self._content = "test"

    # -- queries ----------------------------------------------------------------------
    @property
    def in_blank(self) -> bool:
        return self.blank_until is not None

    @property
    def may_rate(self) -> bool:
        return self.viewing_s >= self.min_view_s and not self.in_blank

    @property
    def may_submit(self) -> bool:
        return self.slider.is_set and self.viewing_s >= self.min_view_s

    def notice_active(self, now: float) -> bool:
        return now < self.notice_until

    def notice_text(self) -> str:
        if self.phase == RATE and not self.slider.is_set:
            return "Set the slider first"
        return f"Please watch for at least {self.min_view_s:.1f} s"

    # -- input ------------------------------------------------------------------------
    def command(self, cmd: Command, now: float) -> list[Action]:
        """Apply one participant command at monotonic time ``now``."""
        name = cmd.name
        if name == "pause":
            return [Action("pause")]
        if self.phase == VIEW:
            if name == "switch" and not self.in_blank:
                target = "reference" if self.showing == "test" else "test"
                self.n_toggles += 1
                self._switch_key_t = now
                if self.t_start is not None:
                    self.toggle_times_ms.append(1000 * (now - self.t_start))
                if self.blank_n > 0:
                    self.blank_until = self.n + self.blank_n
                    self.blank_target = target
                else:
                    self.showing = target
                return [Action("log", {"state": "switch", "to": target})]
            if name == "rate":
                if self.may_rate:
                    self.phase = RATE
                    self.stats.break_chain()
                    return [Action("rating_opened")]
                self.notice_until = now + NOTICE_SECONDS
                return [Action("notice")]
            return []
        # the rating screen
        if name == "back":
            self.phase = VIEW
            return [Action("viewing_resumed")]
        if name == "step":
            self.slider.key_step(cmd.direction, cmd.coarse, now)
            return [Action("log", {"state": "slider", "value": f"{self.slider.value:.3f}"})]
        if name == "press":
            if self.slider.press(cmd.x, cmd.y, now):
                return [Action("log", {"state": "slider", "value": f"{self.slider.value:.3f}"})]
            return []
        if name == "drag":
            self.slider.drag(cmd.x)
            return []
        if name == "release":
            was = self.slider.dragging
            self.slider.release()
            if was:
                return [Action("log", {"state": "slider", "value": f"{self.slider.value:.3f}"})]
            return []
        if name == "submit":
            if self.may_submit:
                return [Action("submitted", result=self.result(now))]
            self.notice_until = now + NOTICE_SECONDS
            return [Action("notice")]
        return []

    # -- presentation -----------------------------------------------------------------
    def next_frame(self) -> tuple[str, int]:
        """What the coming refresh shows: ``test``, ``reference`` or ``blank``, and the
        video frame index of the presentation clock (the same for both videos)."""
        if self.blank_until is not None and self.n >= self.blank_until:
            self.showing = self.blank_target or self.showing
            self.blank_until = None
        self._content = "blank" if self.blank_until is not None else self.showing
        return self._content, frame_index(self.n, self.fps, self.refresh_hz, self.frames,
                                          loop=self.loop)

    def flipped(self, t: float, *, chained: bool = True) -> None:
        """The frame from :meth:`next_frame` (view phase) or the rating screen was shown at
        monotonic time ``t``. ``chained=False`` marks a gap that is no presentation interval
        (e.g. a screenshot was read back before this flip)."""
        self.flips += 1
        if self.phase != VIEW:
            self._last_content = None
            return
        if not chained:
            self.stats.break_chain()
        interval = self.stats.add(t)
        content = self._content
        if self.t_start is None:
            self.t_start = t
            self._cpu_start = self.cpu_clock()
            self.presented_at = self.wall_clock()
        if interval is not None and self._last_content is not None:
            if self._last_content != "blank":
                self.ms_on[self._last_content] += 1000 * interval
            self.viewing_s += interval
        if content == "blank" and self._last_content != "blank":
            self._blank_started_t = t
            self._blank_started_n = self.n
        if content != "blank" and self._switch_key_t is not None and self.blank_until is None:
            self.switch_latencies_ms.append(1000 * (t - self._switch_key_t))
            if self._blank_started_t is not None:
                self.blank_durations_ms.append(1000 * (t - self._blank_started_t))
                self.blank_refresh_counts.append(self.n - self._blank_started_n)
                self._blank_started_t = None
            self._switch_key_t = None
        self._last_content = content
        self.n += refreshes_elapsed(interval, self.period) if interval is not None else 1

    # -- outcome ----------------------------------------------------------------------
    def result(self, now: float) -> TrialResult:
        """The trial's record (times in ms from its first frame)."""
        t0 = self.t_start if self.t_start is not None else now
        s = self.slider
        stats = self.stats
        return TrialResult(
            rating=float(s.value) if s.value is not None else float("nan"),
            rt_ms=1000 * (now - t0),
            n_toggles=self.n_toggles,
            ms_on_reference=self.ms_on["reference"],
            ms_on_test=self.ms_on["test"],
            presented_at=self.presented_at or self.wall_clock(),
            slider_first_move_ms=(1000 * (s.first_touch - t0)
                                  if s.first_touch is not None else None),
            frames_presented=stats.frames_presented,
            dropped_frames=stats.dropped_frames,
            max_flip_interval_ms=stats.max_interval_ms,
            switch_latencies_ms=list(self.switch_latencies_ms),
            details={
                "vsync": self.vsync, "refresh_hz": self.refresh_hz, "fps": self.fps,
                "p99_flip_interval_ms": stats.percentile_interval_ms(99),
                "missed_refreshes": stats.missed_refreshes,
                "blank_durations_ms": list(self.blank_durations_ms),
                "blank_refreshes": list(self.blank_refresh_counts),
                "blank_target_refreshes": self.blank_n,
                "toggle_times_ms": list(self.toggle_times_ms),
                "viewing_ms": 1000 * self.viewing_s,
                # CPU time of the whole process (all threads) per flip: what the machine needs
                # to keep up, independent of how loaded it was.
                "cpu_ms_per_flip": 1000 * (self.cpu_clock() - self._cpu_start)
                / max(1, self.flips - 1),
                **self.details,
            },
        )
