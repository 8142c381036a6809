"""Per-flip instrumentation of the player, for finding where a stall comes from.

Installed in the benchmark's own process (the player runs in-process there), it wraps the
display's flip, the clock pacer's wait and pygame's event pump, and listens to Python's
garbage collector, so that every flip interval can be split into: drawing and input handling
(from the previous flip's return to this flip's call), the event pump, the GPU finish before
the pacer, the pacer's wake-up overshoot, the swap itself, time inside a GC pass, and the
main thread's involuntary context switches (Linux). A stall is an interval over 1.5 refresh
periods; :func:`attribute` names its largest excess component.
"""

from __future__ import annotations

import gc
import itertools
import resource
import time
from dataclasses import dataclass, field
from typing import Any

COMPONENTS = ("work", "event_pump", "finish", "pacer_overshoot", "swap", "gc")


@dataclass
class FlipRecord:
    t: float  # monotonic time the flip returned
    work: float = 0.0
    event_pump: float = 0.0
    finish: float = 0.0
    pacer_overshoot: float = 0.0
    swap: float = 0.0
    gc: float = 0.0
    gc_passes: int = 0
    nivcsw: int = 0


@dataclass
class FlipProbe:
    records: list[FlipRecord] = field(default_factory=list)
    _last_return: float | None = None
    _pump: float = 0.0
    _gc_start: float | None = None
    _gc_time: float = 0.0
    _gc_passes: int = 0
    _wait_start: float | None = None
    _wait_slot: float | None = None
    _wait_wake: float | None = None
    _nivcsw: int = 0
    _saved: list[tuple[Any, str, Any]] = field(default_factory=list)

    # -- installing -----------------------------------------------------------------------
    def install(self) -> FlipProbe:
        import pygame

        from study_app import clock, display

        probe = self
        orig_flip = display.Display.flip
        orig_wait = clock.FlipPacer.wait
        orig_get = pygame.event.get

        def wait(pacer: Any) -> float:
            probe._wait_start = time.perf_counter()
            slot = orig_wait(pacer)
            probe._wait_slot, probe._wait_wake = slot, time.perf_counter()
            return slot

        def get(*args: Any, **kw: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return orig_get(*args, **kw)
            finally:
                probe._pump += time.perf_counter() - t0

        def flip(disp: Any) -> float:
            t_call = time.perf_counter()
            probe._wait_slot = probe._wait_wake = probe._wait_start = None
            t_ret = orig_flip(disp)
            probe._record(t_call, t_ret)
            return t_ret

        for owner, name, new, old in ((display.Display, "flip", flip, orig_flip),
                                      (clock.FlipPacer, "wait", wait, orig_wait),
                                      (pygame.event, "get", get, orig_get)):
            self._saved.append((owner, name, old))
            setattr(owner, name, new)
        gc.callbacks.append(self._on_gc)
        self._nivcsw = self._switches()
        return self

    def uninstall(self) -> None:
        for owner, name, old in self._saved:
            setattr(owner, name, old)
        self._saved.clear()
        if self._on_gc in gc.callbacks:
            gc.callbacks.remove(self._on_gc)

    # -- recording ------------------------------------------------------------------------
    @staticmethod
    def _switches() -> int:
        try:
            return resource.getrusage(resource.RUSAGE_THREAD).ru_nivcsw
        except (AttributeError, ValueError, OSError):
            return 0

    def _on_gc(self, phase: str, info: dict[str, Any]) -> None:
        now = time.perf_counter()
        if phase == "start":
            self._gc_start = now
        elif self._gc_start is not None:
            self._gc_time += now - self._gc_start
            self._gc_passes += 1
            self._gc_start = None

    def _record(self, t_call: float, t_ret: float) -> None:
        rec = FlipRecord(t_ret)
        if self._last_return is not None:
            rec.work = max(0.0, t_call - self._last_return - self._pump)
        rec.event_pump = self._pump
        if self._wait_slot is not None and self._wait_wake is not None:
            # Display.flip: finish() (rasterise), the pacer's wait for its slot, the swap
            rec.finish = max(0.0, (self._wait_start or t_call) - t_call)
            rec.pacer_overshoot = max(0.0, self._wait_wake - self._wait_slot)
            rec.swap = t_ret - self._wait_wake
        else:
            rec.swap = t_ret - t_call
        rec.gc, rec.gc_passes = self._gc_time, self._gc_passes
        n = self._switches()
        rec.nivcsw, self._nivcsw = n - self._nivcsw, n
        self._pump = self._gc_time = 0.0
        self._gc_passes = 0
        self._last_return = t_ret
        self.records.append(rec)

    def reset(self) -> None:
        self.records.clear()
        self._last_return = None


def stalls(records: list[FlipRecord], period_s: float, factor: float = 1.5
           ) -> list[tuple[float, FlipRecord]]:
    """(interval, record) of every flip interval over ``factor`` periods."""
    out = []
    for a, b in itertools.pairwise(records):
        interval = b.t - a.t
        if interval > factor * period_s:
            out.append((interval, b))
    return out


def attribute(interval: float, rec: FlipRecord, period_s: float) -> str:
    """The component that explains most of a stall (or 'preempted' when none does and the
    thread was switched out involuntarily, else 'unexplained')."""
    budget = {"work": 0.3 * period_s, "event_pump": 0.002, "finish": 0.6 * period_s,
              "pacer_overshoot": 0.002, "swap": 0.004, "gc": 0.0}
    excess = {c: getattr(rec, c) - budget[c] for c in COMPONENTS}
    name, value = max(excess.items(), key=lambda kv: kv[1])
    if value > 0.3 * (interval - period_s):
        return name + (" (preempted)" if rec.nivcsw else "")
    return "preempted" if rec.nivcsw else "unexplained"


# -- is it us, or the machine? ----------------------------------------------------------------
CANARY = """
import sys, time
out, stop = sys.argv[1], sys.argv[2]
import os
late = []
t = time.perf_counter()
while not os.path.exists(stop):
    time.sleep(0.001)
    now = time.perf_counter()
    if now - t > 0.006:
        late.append((t, now))
    t = now
with open(out, "w") as fh:
    fh.write("\\n".join(f"{a} {b}" for a, b in late))
"""


class Canary:
    """A separate, almost always sleeping process that notes when it woke up late: when it
    was held up at the same moment as the player, the machine (the hypervisor or another
    process) took the CPU from both; the player's own work cannot explain that."""

    def __init__(self, workdir: Any) -> None:
        import subprocess
        import sys
        from pathlib import Path

        self._out = Path(workdir) / "canary.txt"
        self._stop = Path(workdir) / "canary.stop"
        self._stop.unlink(missing_ok=True)
        self._proc = subprocess.Popen([sys.executable, "-c", CANARY, str(self._out),
                                       str(self._stop)])
        self.gaps: list[tuple[float, float]] = []
        self.steal_start = steal_jiffies()
        self.steal = 0

    def stop(self) -> None:
        self._stop.touch()
        self._proc.wait(timeout=10)
        self.steal = steal_jiffies() - self.steal_start
        text = self._out.read_text() if self._out.is_file() else ""
        self.gaps = [tuple(map(float, line.split())) for line in text.splitlines() if line]

    def overlap(self, start: float, end: float) -> float:
        """Longest canary gap overlapping [start, end] (seconds)."""
        best = 0.0
        for a, b in self.gaps:
            if a < end and b > start:
                best = max(best, b - a)
        return best


def steal_jiffies() -> int:
    """CPU time the hypervisor gave to others (``steal`` in /proc/stat), in clock ticks."""
    try:
        with open("/proc/stat", encoding="ascii") as fh:
            fields = fh.readline().split()
        return int(fields[8])
    except (OSError, IndexError, ValueError):
        return 0
