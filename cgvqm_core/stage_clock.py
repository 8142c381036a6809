"""Where a scoring run spends its time: decode, copy, backbone, pooling and the rest.

A :class:`StageClock` handed to :func:`cgvqm_core.stream.run` (or ``CGVQM.score_many``)
adds up the time of each stage:

- ``decode``: reading, resizing, resampling and padding frames into clips (host time; when
  decoding runs ahead, the sum over the decode threads, one per video, which overlap each
  other and everything else);
- ``wait``: time the scorer waited for a decoded clip (only with prefetching);
- ``copy``: moving a clip to the device and turning uint8 into the normalised float input;
- ``backbone``: the network's stages and the unit normalisation of their outputs;
- ``pooling``: squared differences, their means per channel and frame, error maps, and
  bringing the numbers back to the host.

On a CPU these are host intervals (the work is synchronous). On CUDA the device stages are
timed with CUDA events on the current stream, read once at the end (no synchronisation per
stage, so timing does not change what it measures); ``idle`` is then the wall time the GPU
did none of them. Every stage is also a ``torch.profiler`` range named ``cgvqm/<stage>``, so a
profiler trace shows the same split.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator

import torch

STAGES = ("decode", "wait", "copy", "backbone", "pooling")
DEVICE_STAGES = ("copy", "backbone", "pooling")


class StageClock:
    """Adds up seconds per stage of one or more scoring runs on ``device``."""

    def __init__(self, device: str | torch.device = "cpu") -> None:
        self.device = torch.device(device)
        self.cuda = self.device.type == "cuda"
        self._host: dict[str, float] = dict.fromkeys(STAGES, 0.0)
        self._events: list[tuple[str, torch.cuda.Event, torch.cuda.Event]] = []
        self._lock = threading.Lock()
        self.wall = 0.0
        self._t0: float | None = None
        #: set by the run when decoding happened in the prefetch thread
        self.overlapped = False

    def start(self) -> None:
        """Begin the wall-clock interval (``stop`` ends it; several intervals add up)."""
        if self.cuda:
            torch.cuda.synchronize(self.device)
        self._t0 = time.perf_counter()

    def stop(self) -> None:
        if self._t0 is None:
            return
        if self.cuda:
            torch.cuda.synchronize(self.device)
        self.wall += time.perf_counter() - self._t0
        self._t0 = None

    def add(self, stage: str, seconds: float) -> None:
        """Host seconds measured elsewhere (the decode thread)."""
        with self._lock:
            self._host[stage] += seconds

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block as ``name`` (device time on CUDA for the device stages)."""
        with torch.profiler.record_function(f"cgvqm/{name}"):
            if self.cuda and name in DEVICE_STAGES:
                start = torch.cuda.Event(enable_timing=True)
                end = torch.cuda.Event(enable_timing=True)
                start.record()
                try:
                    yield
                finally:
                    end.record()
                    self._events.append((name, start, end))
                return
            t0 = time.perf_counter()
            try:
                yield
            finally:
                self.add(name, time.perf_counter() - t0)

    def seconds(self) -> dict[str, float]:
        """Seconds per stage, plus ``idle``: wall time not spent in any stage on the path
        that bounds it (the host on a CPU, the GPU on CUDA; decode counts only when it ran
        on that path, i.e. without prefetching)."""
        out = dict(self._host)
        if self._events:
            torch.cuda.synchronize(self.device)
            for name, start, end in self._events:
                out[name] += start.elapsed_time(end) / 1e3
        busy = sum(out[s] for s in DEVICE_STAGES)
        if not self.cuda:
            busy += out["wait"] + (0.0 if self.overlapped else out["decode"])
        out["idle"] = max(self.wall - busy, 0.0)
        out["wall"] = self.wall
        return out

    def report(self) -> str:
        """One line: each stage's seconds and share of the wall time."""
        s = self.seconds()
        wall = max(s["wall"], 1e-12)
        parts = []
        for name in (*STAGES, "idle"):
            if name == "wait" and not self.overlapped:
                continue
            label = "decode (in threads, overlapped)" if (
                name == "decode" and self.overlapped) else name
            parts.append(f"{label} {s[name]:.3f} s ({100 * s[name] / wall:.0f} %)")
        return f"wall {s['wall']:.3f} s: " + ", ".join(parts)


def stage(clock: StageClock | None, name: str) -> contextlib.AbstractContextManager[None]:
    """``clock.stage(name)``, or nothing when no clock is running."""
    return contextlib.nullcontext() if clock is None else clock.stage(name)
