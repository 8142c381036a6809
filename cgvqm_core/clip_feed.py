"""Clips of the reference and its test videos, delivered to the scorer, optionally decoded ahead.

Decoding (PyAV, resizing, resampling, padding) and the network need different resources: on
a GPU, decoding the next clip while the current one is scored removes the decode time from
the run's critical path. With ``prefetch`` a background thread fills the next clip set while
the scorer works on the current one (one set ahead, so memory holds two sets instead of one);
with ``pin`` its buffers are page-locked so the copy to the GPU is a direct, asynchronous
transfer (PyTorch's pinned-memory allocator keeps a buffer until its copy has finished).
Without ``prefetch`` the clips are the reused buffers of :func:`.stream.padded_clips`, as
before (the lowest memory: what a CPU run wants, where decoding is a small share of time).

Errors raised while decoding (a frame-count mismatch, an unreadable file) reach the caller
as they would without the thread, and a caller that stops early stops the thread.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import torch

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
    source = _decoded(ref_clips, test_clips)
    if not prefetch:
        yield from _inline(source, clock)
        return
    if clock is not None:
        clock.overlapped = True
    yield from _ahead(source, pin, clock)


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


def _ahead(source: Iterator[tuple[np.ndarray, int, list[np.ndarray]]], pin: bool,
           clock: StageClock | None) -> Iterator[ClipSet]:
    q: queue.Queue[object] = queue.Queue(maxsize=1)
    stop = threading.Event()

    def put(item: object) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        index = 0
        try:
            while not stop.is_set():
                t0 = time.perf_counter()
                item = next(source, None)
                if item is not None:
                    rclip, valid, tclips = item
                    item = ClipSet(index, valid, _owned(rclip, pin),
                                   [_owned(c, pin) for c in tclips])
                if clock is not None:
                    clock.add("decode", time.perf_counter() - t0)
                if item is None:
                    put(_END)
                    return
                if not put(item):
                    return
                index += 1
        except BaseException as exc:  # handed to the consumer, raised there
            put(exc)

    worker = threading.Thread(target=produce, name="cgvqm-decode", daemon=True)
    worker.start()
    try:
        while True:
            t0 = time.perf_counter()
            item = q.get()
            if clock is not None:
                clock.add("wait", time.perf_counter() - t0)
            if item is _END:
                return
            if isinstance(item, BaseException):
                raise item
            assert isinstance(item, ClipSet)
            yield item
    finally:
        stop.set()
        worker.join()
