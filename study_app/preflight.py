"""Pre-flight checks before the first trial: can this computer show the study exactly?

Each check is a pure function returning a :class:`Check` (name, ok, measured value, message
that says what to change), so the failure messages are testable without a display. The app
measures (window size, flip intervals, decode time) and stores every result in the session.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from stimuli_manifests import DisplayRequirements, validate_manifest

from .errors import StudyError

# Decoding one stimulus pair must fit comfortably into the time a participant spends rating,
# so that the background prefetch is ready when the next trial starts.
MAX_PAIR_DECODE_S = 10.0
# Refresh intervals may scatter this much (relative std) before the display counts as unstable.
MAX_REFRESH_JITTER = 0.10


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


def check_screen(width: int, height: int, req: DisplayRequirements) -> Check:
    ok = width >= req.min_width and height >= req.min_height
    msg = (f"screen {width}x{height} (study needs at least {req.min_width}x{req.min_height})"
           if ok else
           f"the screen is {width}x{height} pixels but this study needs at least "
           f"{req.min_width}x{req.min_height}: use a larger or higher-resolution monitor, set "
           "it to its native resolution, and set display scaling to 100%")
    return Check("screen_size", ok, msg, {"width": width, "height": height})


def check_refresh(intervals_s: Sequence[float], req: DisplayRequirements, *, vsync: bool,
                  paced_hz: float | None = None) -> Check:
    """Refresh rate from measured flip intervals; without vsync, the pacing rate is reported."""
    if not vsync:
        hz = float(paced_hz or 0.0)
        ok = hz >= req.min_refresh_hz
        msg = (f"vsync is not available (e.g. a virtual display): flips are paced by the "
               f"monotonic clock at {hz:g} Hz" if ok else
               f"vsync is not available and the pacing rate {hz:g} Hz is below the study's "
               f"minimum {req.min_refresh_hz:g} Hz: pass --refresh-hz with your monitor's rate")
        return Check("refresh_rate", ok, msg, {"vsync": False, "hz": hz}, warning=True)
    if len(intervals_s) < 10:
        return Check("refresh_rate", False, "too few flips measured to know the refresh rate; "
                     "close other programs and try again", {"vsync": True})
    med = statistics.median(intervals_s)
    hz = 1.0 / med if med > 0 else 0.0
    jitter = statistics.pstdev(intervals_s) / med if med > 0 else float("inf")
    value = {"vsync": True, "hz": round(hz, 3), "jitter": round(jitter, 4),
             "n": len(intervals_s)}
    if hz < req.min_refresh_hz:
        return Check("refresh_rate", False,
                     f"the display refreshes at {hz:.1f} Hz but this study needs at least "
                     f"{req.min_refresh_hz:g} Hz: set the monitor to {req.min_refresh_hz:g} Hz "
                     "or more in the display settings", value)
    if jitter > MAX_REFRESH_JITTER:
        return Check("refresh_rate", False,
                     f"the refresh timing is unstable ({100 * jitter:.0f}% variation): close "
                     "other programs, plug in the laptop, disable power saving, and try again",
                     value)
    return Check("refresh_rate", True, f"refresh {hz:.2f} Hz, stable ({100 * jitter:.1f}% "
                 "variation)", value)


def check_pixel_mapping(window: tuple[int, int], drawable: tuple[int, int],
                        video: tuple[int, int]) -> Check:
    value = {"window": list(window), "drawable": list(drawable), "video": list(video)}
    if tuple(window) != tuple(drawable):
        return Check("pixel_mapping", False,
                     f"the drawing surface is {drawable[0]}x{drawable[1]} for a "
                     f"{window[0]}x{window[1]} window, so videos would be rescaled: set "
                     "display scaling to 100% (no HiDPI scaling) and restart", value)
    if video[0] > window[0] or video[1] > window[1]:
        return Check("pixel_mapping", False,
                     f"the videos ({video[0]}x{video[1]}) do not fit the window "
                     f"({window[0]}x{window[1]}) at 1:1 pixels: run full screen on a larger "
                     "monitor", value)
    return Check("pixel_mapping", True, "1:1 pixel mapping", value)


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


def check_memory(needed_bytes: int, available_bytes: int | None) -> Check:
    gib = 1024**3
    value = {"needed": needed_bytes, "available": available_bytes}
    if available_bytes is None:
        return Check("memory", True, "available memory unknown on this system", value,
                     warning=True)
    ok = available_bytes >= needed_bytes
    msg = (f"{available_bytes / gib:.1f} GiB available, {needed_bytes / gib:.1f} GiB needed"
           if ok else
           f"only {available_bytes / gib:.1f} GiB of memory is free but the decoded videos "
           f"need {needed_bytes / gib:.1f} GiB: close other programs (browsers, games) or use "
           "a computer with more memory")
    return Check("memory", ok, msg, value)


def check_decode_speed(seconds: float, limit_s: float = MAX_PAIR_DECODE_S) -> Check:
    ok = seconds <= limit_s
    msg = (f"one stimulus pair decodes in {seconds:.2f} s" if ok else
           f"decoding one stimulus pair took {seconds:.1f} s (limit {limit_s:g} s), so the next "
           "trial would not be ready in time: close other programs or use a faster computer")
    return Check("decode_speed", ok, msg, {"seconds": round(seconds, 3)})


def check_checksums(study: Any) -> Check:
    """All stimulus files present and matching the manifest's sha256."""
    t0 = time.perf_counter()
    report = validate_manifest(study.loaded, verify_checksums=True, progress=False)
    problems = report.errors + [str(m) for m in report.mismatches]
    value = {"files": report.checked_files, "seconds": round(time.perf_counter() - t0, 3),
             "unverified": len(report.warnings)}
    if problems:
        return Check("checksums", False,
                     "stimulus files are missing or modified (" + "; ".join(problems[:3]) +
                     (" ..." if len(problems) > 3 else "") +
                     "): download or unpack the study folder again", value)
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
            + " (experimenters: --skip-preflight runs anyway and records it)"
        )
