"""The background statistics grow with the study (seconds at thousands of ratings); run back
to back they kept a core busy all the time. After each run the statistics' worker rests at
least twice as long as the run took, whatever the pokes (the allocation's refit, which
participants' blocks wait on, does not)."""

from __future__ import annotations

import threading
import time

from study_server.worker import REST_FACTOR, ThrottledWorker


def test_a_slow_run_is_followed_by_a_rest_twice_as_long():
    starts: list[float] = []
    ends: list[float] = []
    done = threading.Event()

    def work() -> None:
        starts.append(time.monotonic())
        time.sleep(0.3)
        ends.append(time.monotonic())
        if len(starts) >= 3:
            done.set()

    w = ThrottledWorker("test", 0.01, work, rest_factor=REST_FACTOR)  # as the statistics
    w.start()
    try:
        deadline = time.monotonic() + 10
        while not done.is_set() and time.monotonic() < deadline:
            w.poke()  # a busy study pokes after every upload
            time.sleep(0.01)
    finally:
        w.stop()
    assert len(starts) >= 3
    for end, took, nxt in zip(ends, [e - s for s, e in zip(starts, ends, strict=False)],
                              starts[1:], strict=False):
        assert nxt - end >= REST_FACTOR * took - 0.02  # rested (timer slack aside)
    busy = sum(e - s for s, e in zip(starts[:3], ends[:3], strict=True))
    assert busy / (ends[2] - starts[0]) < 0.45  # about a third of the time, not all of it
