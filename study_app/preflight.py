"""Pre-flight checks before the first trial: can this computer show the study exactly?

Each check is a pure function returning a :class:`Check` (name, ok, measured value, message
that says what to change), so the failure messages are testable without a display. The app
measures (window size, flip intervals, decode time) and stores every result in the session.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from session_store.errors import StudyError
from stimuli_manifests import DisplayRequirements, validate_manifest

from .vsync import RefreshEstimate

# Decoding one stimulus pair must fit comfortably into the time a participant spends rating,
# so that the background prefetch is ready when the next trial starts.
MAX_PAIR_DECODE_S = 10.0
# Refresh intervals may scatter this much (relative std) before the display counts as unstable.
MAX_REFRESH_JITTER = 0.10
# Share of refreshes the pre-flight's own flips may miss before the computer counts as busy.
MAX_PREFLIGHT_DROPPED_SHARE = 0.05


@dataclass
class Check:
    """One pre-flight result (stored in the session as a dict)."""

    name: str
    ok: bool
    message: str
    value: dict[str, Any] = field(default_factory=dict)
    warning: bool = False

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _on(monitor: str | None) -> str:
    """" (DELL U2720Q)": the monitor's name where the system gives a real one."""
    generic = monitor is None or monitor.strip().lower() in ("", "screen", "display")
    return "" if generic else f" ({monitor})"


def check_screen(width: int, height: int, req: DisplayRequirements, *,
                 monitor: str | None = None) -> Check:
    """The monitor the window is on has at least the study's minimum resolution (pixels)."""
    ok = width >= req.min_width and height >= req.min_height
    msg = (f"{width}x{height} pixels{_on(monitor)}; the study needs at least "
           f"{req.min_width}x{req.min_height}" if ok else
           f"the screen{_on(monitor)} shows {width}x{height} pixels but this study needs at "
           f"least {req.min_width}x{req.min_height}: set the screen to its highest "
           "(native) resolution in the display settings, set display scaling to 100%, or use "
           "a larger monitor")
    return Check("screen_size", ok, msg, {"width": width, "height": height,
                                          "monitor": monitor})


def check_refresh(est: RefreshEstimate | None, req: DisplayRequirements, *,
                  paced_pilot: bool, paced_hz: float | None = None) -> Check:
    """The refresh rate measured from vsync'd flips; without vsync only a pilot may run.

    ``paced_pilot`` is the experimenter's explicit pilot/test mode (flips paced on the
    monotonic clock at ``paced_hz``): it passes with a warning and is recorded as such.
    """
    if paced_pilot:
        hz = float(paced_hz or 0.0)
        value = {"vsync": False, "hz": hz, "timing_mode": "paced-pilot",
                 "measured": est.as_dict() if est is not None else None}
        return Check("refresh_rate", hz > 0, f"pilot/test mode without vsync: flips paced by "
                     f"the clock at {hz:g} Hz (not valid for participant data)", value,
                     warning=True)
    if est is None or est.n_intervals < 10:
        return Check("refresh_rate", False, "the screen's refresh could not be measured: "
                     "close other programs and start again", {"vsync": None})
    value = {"timing_mode": "vsync", **est.as_dict()}
    if not est.vsync:
        return Check(
            "refresh_rate", False,
            "this computer does not wait for the screen's refresh when it shows a picture "
            "(vertical sync is off), so video timing would be wrong: turn on vertical sync "
            "(\"wait for vertical refresh\", \"V-Sync\") in the graphics driver's settings or "
            "update the graphics driver, close screen-recording or remote-desktop programs, "
            "and start again", value)
    if est.hz < req.min_refresh_hz - 0.5:
        return Check("refresh_rate", False,
                     f"the screen refreshes at {est.hz:.1f} Hz but this study needs at least "
                     f"{req.min_refresh_hz:g} Hz: set the refresh rate to "
                     f"{max(60, round(req.min_refresh_hz)):g} Hz or more in the display "
                     "settings", value)
    if est.variable or est.jitter > MAX_REFRESH_JITTER:
        return Check("refresh_rate", False,
                     "the screen's refresh is irregular: turn off variable refresh rate "
                     "(G-SYNC, FreeSync, Adaptive-Sync, ProMotion) in the display settings, "
                     "close other programs, plug in the laptop's charger, and start again",
                     value)
    if est.dropped > MAX_PREFLIGHT_DROPPED_SHARE * est.n_intervals:
        return Check("refresh_rate", False,
                     f"the computer missed {est.dropped} of {est.n_intervals} screen refreshes "
                     "while testing: close other programs (browsers, video calls, games), "
                     "plug in the laptop's charger, and start again", value)
    return Check("refresh_rate", True, f"refresh {est.hz:.2f} Hz, steady "
                 f"({100 * est.jitter:.1f}% variation)", value)


@dataclass(frozen=True)
class Monitor:
    """One monitor: its SDL display index, name and bounds in the OS's window units."""

    index: int
    name: str
    bounds: tuple[int, int, int, int]


@dataclass(frozen=True)
class PixelGeometry:
    """How the window's pixels reach the monitor.

    ``window`` is in the OS's window units, ``drawable`` in framebuffer pixels (twice the
    window on a macOS Retina screen). ``os_scale`` is the OS display scaling of the window's
    monitor (1.25 = 125 %) where known; ``os_stretches`` says the OS resamples the window
    (a process without DPI awareness on a scaled Windows monitor).
    """

    window: tuple[int, int]
    drawable: tuple[int, int]
    monitors: tuple[Monitor, ...] = ()
    window_pos: tuple[int, int] | None = None
    monitor_index: int | None = None
    os_scale: float | None = None
    os_stretches: bool = False

    @property
    def pixel_ratio(self) -> float:
        return self.drawable[0] / self.window[0] if self.window[0] else 1.0

    def monitor(self) -> Monitor | None:
        """The monitor the window is on (by SDL's index, else by the largest overlap)."""
        if self.monitor_index is not None:
            for mon in self.monitors:
                if mon.index == self.monitor_index:
                    return mon
        if self.window_pos is None or not self.monitors:
            return self.monitors[0] if self.monitors else None
        return max(self.monitors, key=lambda m: _overlap(self._window_rect(), m.bounds))

    def _window_rect(self) -> tuple[int, int, int, int]:
        assert self.window_pos is not None
        return (*self.window_pos, *self.window)

    def spans_monitors(self) -> bool:
        if self.window_pos is None or len(self.monitors) < 2:
            return False
        rect = self._window_rect()
        return sum(1 for m in self.monitors if _overlap(rect, m.bounds) > 0) > 1


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> int:
    w = min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0])
    h = min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1])
    return max(0, w) * max(0, h)


def _percent(scale: float) -> str:
    return f"{round(100 * scale)}%"


def check_pixel_mapping(geom: PixelGeometry, video: tuple[int, int], *,
                        fits_with_label: bool = True) -> Check:
    """One video pixel is one physical pixel of the monitor the window is on."""
    mon = geom.monitor()
    name = mon.name if mon else None
    value = {"window": list(geom.window), "drawable": list(geom.drawable),
             "video": list(video), "monitor": name, "monitor_index": mon.index if mon else None,
             "monitors": len(geom.monitors), "os_scale": geom.os_scale,
             "os_stretches": geom.os_stretches, "pixel_ratio": geom.pixel_ratio}
    rx = geom.drawable[0] / geom.window[0] if geom.window[0] else 0
    ry = geom.drawable[1] / geom.window[1] if geom.window[1] else 0
    if abs(rx - ry) > 1e-6 or abs(rx - round(rx)) > 1e-6 or round(rx) < 1:
        return Check("pixel_mapping", False,
                     f"display scaling is {_percent(rx)}{_on(name)}, so videos would be "
                     "resampled: set display scaling (\"Scale\", \"Resolution: scaled\") to 100% "
                     "in the display settings and start again", value)
    if geom.os_stretches and geom.os_scale is not None and abs(geom.os_scale - 1) > 1e-3:
        return Check("pixel_mapping", False,
                     f"display scaling is {_percent(geom.os_scale)}{_on(name)}, so the system "
                     "would enlarge the videos: set display scaling to 100% in the display "
                     "settings and start again", value)
    if geom.spans_monitors():
        return Check("pixel_mapping", False,
                     "the study window lies across two monitors: move it entirely onto the "
                     "main monitor (or disconnect the other monitor) and start again", value)
    if len(geom.monitors) > 1 and mon is not None and mon.index != 0:
        return Check("pixel_mapping", False,
                     f"the study opened on a second monitor ({mon.name}), where its timing "
                     "cannot be trusted: make the monitor you want to use the main display "
                     "in the display settings (or disconnect the other monitors) and start "
                     "again", value)
    drawable = geom.drawable
    if video[0] > drawable[0] or video[1] > drawable[1]:
        return Check("pixel_mapping", False,
                     f"the videos ({video[0]}x{video[1]} pixels) do not fit on the screen "
                     f"({drawable[0]}x{drawable[1]}){_on(name)}: set the screen to its "
                     "highest resolution and display scaling to 100%, or use a larger "
                     "monitor", value)
    if not fits_with_label:
        return Check("pixel_mapping", False,
                     f"the screen ({drawable[0]}x{drawable[1]}){_on(name)} leaves no room "
                     "beside the videos for their labels: set the screen to a higher "
                     "resolution or use a larger monitor", value)
    scale = f", display scaling {_percent(geom.os_scale)}" if geom.os_scale else ""
    return Check("pixel_mapping", True,
                 f"1:1 pixels on {name or 'the screen'}{scale}", value)


def available_memory_bytes() -> int | None:
    """Memory available to new allocations (Linux /proc/meminfo, else sysconf), or None."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _size(n: int) -> str:
    """Bytes in the units a participant's computer shows (GB and MB, powers of ten)."""
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{max(1, round(n / 1e6))} MB"


def check_memory(needed_bytes: int, available_bytes: int | None) -> Check:
    value = {"needed": needed_bytes, "available": available_bytes}
    if available_bytes is None:
        return Check("memory", True, "available memory unknown on this system", value,
                     warning=True)
    ok = available_bytes >= needed_bytes
    msg = (f"{_size(available_bytes)} available, {_size(needed_bytes)} needed"
           if ok else
           f"only {_size(available_bytes)} of memory is free but the decoded videos "
           f"need {_size(needed_bytes)}: close other programs (browsers, games) or use "
           "a computer with more memory")
    return Check("memory", ok, msg, value)


def check_decode_speed(seconds: float, limit_s: float = MAX_PAIR_DECODE_S) -> Check:
    ok = seconds <= limit_s
    msg = (f"the videos load fast enough ({seconds:.2f} s per pair)" if ok else
           f"loading one pair of videos took {seconds:.1f} s (limit {limit_s:g} s), so the next "
           "trial would not be ready in time: close other programs or use a faster computer")
    return Check("decode_speed", ok, msg, {"seconds": round(seconds, 3)})


def check_checksums(study: Any, *, from_server: bool = False,
                    known_sha256: Mapping[Path, str] | None = None) -> Check:
    """All stimulus files present and matching the manifest's sha256. ``from_server``: the
    study was downloaded from a study server, which sends damaged files again at the next
    start (a participant has no study folder to unpack). ``known_sha256``: files the
    download hashed in this run (resolved path to sha256), compared without reading them
    again."""
    t0 = time.perf_counter()
    report = validate_manifest(study.loaded, verify_checksums=True, progress=False,
                               known_sha256=known_sha256)
    problems = report.errors + [str(m) for m in report.mismatches]
    value = {"files": report.checked_files, "seconds": round(time.perf_counter() - t0, 3),
             "unverified": len(report.warnings)}
    if problems:
        return Check("checksums", False,
                     "stimulus files are missing or modified (" + "; ".join(problems[:3]) +
                     (" ..." if len(problems) > 3 else "") + "): " +
                     ("close this window and start the study again: damaged files are "
                      "downloaded again" if from_server else
                      "download or unpack the study folder again"), value)
    if report.warnings:
        return Check("checksums", True, f"{len(report.warnings)} file(s) have no recorded "
                     "checksum", value, warning=True)
    return Check("checksums", True, f"{report.checked_files} files match the manifest", value)


def raise_for_failures(checks: Sequence[Check]) -> None:
    """Raise one :class:`StudyError` listing every failed check's message."""
    failed = [c for c in checks if not c.ok]
    if failed:
        raise StudyError(
            "pre-flight failed: " + " | ".join(f"{c.name}: {c.message}" for c in failed)
        )
