"""Clips of the reference and its test videos, delivered to the scorer, optionally decoded ahead.

Decoding (PyAV, resizing, resampling, padding) and the network need different resources: on
a GPU, decoding the next clip while the current one is scored removes the decode time from
the run's critical path. With ``prefetch`` background threads, one per video (so the
reference and its tests decode in parallel), fill the next clip set while the scorer works
on the current one (one set ahead, so memory holds two sets instead of one); with ``pin``
their buffers are page-locked so the copy to the GPU is a direct, asynchronous
transfer (PyTorch's pinned-memory allocator keeps a buffer until its copy has finished).
Without ``prefetch`` the clips are the reused buffers of :func:`.stream.padded_clips`, as
before (the lowest memory: what a CPU run wants, where decoding is a small share of time).

Errors raised while decoding (a frame-count mismatch, an unreadable file) reach the caller
as they would without the threads, and a caller that stops early stops them.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from .errors import CGVQMError
from .stage_clock import StageClock

ClipIter = Iterator[tuple[np.ndarray, int]]
_END = object()
_POLL_S = 0.1


@dataclass
class ClipSet:
    """One clip of the reference and the same clip of every test video (host, uint8)."""

    index: int
    valid: int  # frames of the clip that are real (the rest repeat its last frame)
    ref: torch.Tensor  # (L, Hp, Wp, 3)
    tests: list[torch.Tensor]


def _decoded(ref_clips: ClipIter, test_clips: Sequence[ClipIter]
             ) -> Iterator[tuple[np.ndarray, int, list[np.ndarray]]]:
    """Reference clips with the test clips beside them; the test streams are run to their
    end afterwards so that their frame-count checks fire."""
    for rclip, valid in ref_clips:
        yield rclip, valid, [next(tc)[0] for tc in test_clips]
    for tc in test_clips:
        for _ in tc:
            pass


def clip_sets(ref_clips: ClipIter, test_clips: Sequence[ClipIter], *, prefetch: bool = False,
              pin: bool = False, clock: StageClock | None = None) -> Iterator[ClipSet]:
    """Clip sets in order; see the module docstring for ``prefetch`` and ``pin``."""
    if not prefetch:
        yield from _inline(_decoded(ref_clips, test_clips), clock)
        return
    if clock is not None:
        clock.overlapped = True
    yield from _ahead([ref_clips, *test_clips], pin, clock)


def _inline(source: Iterator[tuple[np.ndarray, int, list[np.ndarray]]],
            clock: StageClock | None) -> Iterator[ClipSet]:
    index = 0
    while True:
        t0 = time.perf_counter()
        item = next(source, None)
        if clock is not None:
            clock.add("decode", time.perf_counter() - t0)
        if item is None:
            return
        rclip, valid, tclips = item
        yield ClipSet(index, valid, torch.from_numpy(rclip),
                      [torch.from_numpy(c) for c in tclips])
        index += 1


def _owned(clip: np.ndarray, pin: bool) -> torch.Tensor:
    """A copy of a (reused) clip buffer that the consumer may keep."""
    out = torch.empty(clip.shape, dtype=torch.uint8, pin_memory=pin)
    out.numpy()[...] = clip
    return out


class _Reader:
    """One video's clips, decoded ahead in a thread of its own into owned buffers."""

    def __init__(self, clips: ClipIter, name: str, pin: bool, clock: StageClock | None,
                 stop: threading.Event) -> None:
        self.clips, self.pin, self.clock, self.stop = clips, pin, clock, stop
        self.queue: queue.Queue[object] = queue.Queue(maxsize=1)
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def _put(self, item: object) -> bool:
        while not self.stop.is_set():
            try:
                self.queue.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        try:
            while not self.stop.is_set():
                t0 = time.perf_counter()
                item = next(self.clips, None)
                if item is not None:
                    item = (_owned(item[0], self.pin), item[1])
                if self.clock is not None:
                    self.clock.add("decode", time.perf_counter() - t0)
                if item is None:
                    self._put(_END)
                    return
                if not self._put(item):
                    return
        except BaseException as exc:  # handed to the consumer, raised there
            self._put(exc)

    def get(self) -> object:
        item = self.queue.get()
        if isinstance(item, BaseException):
            raise item
        return item


def _ahead(streams: Sequence[ClipIter], pin: bool, clock: StageClock | None
           ) -> Iterator[ClipSet]:
    """Every video decoded in its own thread (PyAV releases the GIL while it decodes and
    converts, so the reference and the tests decode in parallel), one clip ahead."""
    stop = threading.Event()
    readers = [_Reader(clips, "cgvqm-decode", pin, clock, stop) for clips in streams]
    try:
        index = 0
        while True:
            t0 = time.perf_counter()
            head = readers[0].get()
            if head is _END:
                for r in readers[1:]:  # run the test streams to their end (count checks)
                    while r.get() is not _END:
                        pass
                return
            tests = [r.get() for r in readers[1:]]
            if clock is not None:
                clock.add("wait", time.perf_counter() - t0)
            if any(t is _END for t in tests):
                raise CGVQMError("a test video ended before its reference (an internal "
                                 "error: tests are aligned to the reference's frame count)")
            ref, valid = head  # type: ignore[misc]
            yield ClipSet(index, valid, ref, [t[0] for t in tests])  # type: ignore[index]
            index += 1
    finally:
        stop.set()
        for r in readers:
            r.thread.join()
