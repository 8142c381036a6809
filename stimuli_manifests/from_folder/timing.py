"""What a full decode can say about a file beyond its frames: FFmpeg's own error reports,
and timestamps that are not evenly spaced.

Both are invisible in the decoded frames: a damaged slice can decode to wrong pixels
without an exception, and the player and the metrics show every frame for 1/fps whatever
the file's timestamps say, so a render with a dropped-frame gap would play smoothly in the
study although a media player shows the stutter.
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import av
import av.logging

# An interval this far from the median interval is a gap or a burst, not rounding of
# millisecond timestamps (30 fps in Matroska alternates 33 and 34 ms).
UNEVEN_RATIO = 1.5


@contextmanager
def decoder_errors() -> Iterator[list[str]]:
    """FFmpeg's messages at error level or worse while the block runs (from every thread:
    decoding runs in FFmpeg's worker threads), as 'codec: message' lines."""
    previous = av.logging.get_level()
    av.logging.set_level(av.logging.ERROR)
    lines: list[str] = []
    try:
        with av.logging.Capture(local=False) as captured:
            yield lines
    finally:
        av.logging.set_level(previous)
    pending = ""
    for level, name, text in captured:  # FFmpeg writes one line in pieces; a newline ends it
        if level > av.logging.ERROR:
            continue
        pending += " " + text
        if text.endswith("\n"):
            lines.append(f"{name}: {' '.join(pending.split())}")
            pending = ""
    if pending.strip():
        lines.append(" ".join(pending.split()))


@dataclass(frozen=True)
class TimestampCheck:
    """The largest uneven frame interval in words (None: evenly spaced), and how many frame
    slots the timestamps skip in all (a 30-frame file whose timestamps span 31 intervals of
    1/fps skips one: it is out of step with an even reference from the gap on)."""

    uneven: str | None = None
    skipped_slots: int = 0


def uneven_timing(container: av.container.InputContainer) -> TimestampCheck:
    """The presentation timestamps of the first video stream, checked; reads every packet of
    that stream (no decoding)."""
    try:
        stream = container.streams.video[0]
        pts = sorted(p.pts for p in container.demux(stream) if p.pts is not None)
        base = stream.time_base
    except (av.error.FFmpegError, IndexError):
        return TimestampCheck()
    if base is None or len(pts) < 3:
        return TimestampCheck()
    steps = [float((b - a) * base) for a, b in itertools.pairwise(pts)]
    typical = statistics.median(steps)
    if typical <= 0:
        return TimestampCheck()
    # the mean of the ordinary intervals (not the median: ms-rounded 30 fps steps are 33 or
    # 34 ms, and 1267 ms / 34 would miss a slot)
    ordinary = [x for x in steps if 1 / UNEVEN_RATIO <= x / typical <= UNEVEN_RATIO]
    skipped = max(0, round(sum(steps) / statistics.fmean(ordinary)) - len(steps))
    worst = max(range(len(steps)), key=lambda i: abs(steps[i] / typical - 1))
    ratio = steps[worst] / typical
    if 1 / UNEVEN_RATIO <= ratio <= UNEVEN_RATIO:
        return TimestampCheck(None, skipped)
    return TimestampCheck(
        f"uneven timestamps: {steps[worst] * 1000:.0f} ms between frames {worst} and "
        f"{worst + 1}, where most are {typical * 1000:.0f} ms (variable frame rate or "
        "dropped frames)", skipped)
