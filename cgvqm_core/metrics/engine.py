"""Scoring one reference and its test videos with several metrics, streamed.

All metrics read through the video source of :mod:`cgvqm_core.stream`: the same decoders,
the same alignment of the test to the reference (bilinear resize of uint8 frames, nearest
resampling in time, logged), the same fps and 8-bit strictness rules. Image metrics share one
decoding pass: frames arrive in small chunks (about 2 Mpixel per chunk), are converted once to
float32 RGB in [0, 1] on the device and handed to every image metric; nothing holds more than
a chunk. Video metrics then make their own pass each.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from ..errors import CGVQMError
from ..stream import (
    FrameSource,
    Geometry,
    _counted,
    aligned_frames,
    alignment_note,
    check_fps,
    check_frame_count,
    open_input,
)
from .registry import FrameScorer, MetricScore, Scorer, VideoScorer

log = logging.getLogger(__name__)

CHUNK_PIXELS = 1 << 21


def open_pair_sources(ref: Any, tests: Sequence[Any], *, fps: float | None = None,
                      allow_resample: bool = False, on_conversion: str = "warn",
                      strict: bool = False
                      ) -> tuple[FrameSource, list[FrameSource], Geometry]:
    """Open the reference and tests as streams and check their frame rates (and, with
    ``strict``, that their frame counts are equal)."""
    rsrc = open_input(ref, fps=fps, name="reference", on_conversion=on_conversion)
    info = rsrc.info
    geom = Geometry(int(info.frame_count), int(info.height), int(info.width), float(info.fps), 1)
    tsrcs = [open_input(t, fps=fps, name=f"test {i}", on_conversion=on_conversion,
                        array_fps=geom.fps) for i, t in enumerate(tests)]
    for t in tsrcs:
        check_fps(rsrc, t, allow_resample)
        check_frame_count(rsrc, t, strict)
    return rsrc, tsrcs, geom


def frame_chunks(ref: FrameSource, tests: Sequence[FrameSource], geom: Geometry,
                 chunk: int) -> Iterator[tuple[np.ndarray, list[np.ndarray]]]:
    """(reference frames, [test frames]) as (k, H, W, 3) uint8, k <= chunk, aligned."""
    rit = _counted(ref, "reference")
    tits = [aligned_frames(t, geom, f"test {i}") for i, t in enumerate(tests)]
    buf_r = np.empty((chunk, geom.height, geom.width, 3), np.uint8)
    buf_t = [np.empty_like(buf_r) for _ in tests]
    n = 0
    for f in rit:
        buf_r[n] = f
        for b, it in zip(buf_t, tits, strict=True):
            b[n] = next(it)
        n += 1
        if n == chunk:
            yield buf_r, buf_t
            n = 0
    if n:
        yield buf_r[:n], [b[:n] for b in buf_t]
    for it in tits:  # run the test streams to their end (frame-count checks)
        for _ in it:
            pass


def chunk_frames(height: int, width: int) -> int:
    return max(1, min(16, CHUNK_PIXELS // max(1, height * width)))


def score_frames_pass(ref: FrameSource, tests: Sequence[FrameSource], geom: Geometry,
                      scorers: Sequence[FrameScorer], device: str, *,
                      progress: bool = False) -> list[list[MetricScore]]:
    """Every image metric over every frame of every test, one decoding pass."""
    import torch

    dev = torch.device(device)
    active = []
    results: list[list[MetricScore]] = [[] for _ in tests]
    for s in scorers:
        why = s.not_applicable(geom.height, geom.width)
        if why:
            for r in results:
                r.append(MetricScore(s.name, s.spec.direction, None, note=why))
        else:
            active.append(s)
    if not active:
        return results
    per_frame: list[list[list[float]]] = [[[] for _ in tests] for _ in active]
    seconds = [0.0] * len(active)
    k = chunk_frames(geom.height, geom.width)
    bar = tqdm(total=geom.frames, desc="image metrics", unit="frame", disable=not progress,
               leave=False)

    def to_tensor(a: np.ndarray) -> Any:
        t = torch.from_numpy(np.ascontiguousarray(a)).to(dev)
        return t.permute(0, 3, 1, 2).to(torch.float32).div_(255.0)

    with torch.inference_mode():
        for rchunk, tchunks in frame_chunks(ref, tests, geom, k):
            r = to_tensor(rchunk)
            for ti, tc in enumerate(tchunks):
                t = to_tensor(tc)
                for si, s in enumerate(active):
                    t0 = time.perf_counter()
                    v = np.asarray(s.score_frames(t, r), dtype=np.float64).reshape(-1)
                    seconds[si] += time.perf_counter() - t0
                    per_frame[si][ti].extend(v.tolist())
            bar.update(len(rchunk))
    bar.close()
    for si, s in enumerate(active):
        for ti in range(len(tests)):
            pf = per_frame[si][ti]
            score = float(np.mean(pf))
            if not np.isfinite(score):
                bad = next(k for k, v in enumerate(pf) if not np.isfinite(v))
                raise CGVQMError(f"{s.name} gave a non-finite score for {tests[ti].info.path} "
                                 f"(frame {bad} of {len(pf)})")
            results[ti].append(MetricScore(
                s.name, s.spec.direction, score, per_frame=pf,
                extra={"seconds": seconds[si] / max(len(tests), 1)}))
    order = {s.name: i for i, s in enumerate(scorers)}
    for r in results:  # in scorer order, as callers match them: not applicable ones first
        r.sort(key=lambda m: order[m.metric])
    return results


def score_reference(ref: Any, tests: Sequence[Any], scorers: Sequence[Scorer], *,
                    device: str = "cpu", fps: float | None = None,
                    allow_resample: bool = False, on_conversion: str = "warn",
                    progress: bool = False, strict: bool = False) -> list[list[MetricScore]]:
    """Score each test against ``ref`` with every scorer; per test, a list of results in
    scorer order (a metric with several poolings gives several results). ``strict`` refuses
    a test whose frame count differs from the reference's instead of resampling it. A test
    that was resized or resampled says so in each of its results' ``note``."""
    rsrc, tsrcs, geom = open_pair_sources(ref, tests, fps=fps, allow_resample=allow_resample,
                                          on_conversion=on_conversion, strict=strict)
    frame = [s for s in scorers if isinstance(s, FrameScorer)]
    by_scorer: dict[int, list[list[MetricScore]]] = {}
    if frame:
        res = score_frames_pass(rsrc, tsrcs, geom, frame, device, progress=progress)
        for j, s in enumerate(frame):
            by_scorer[id(s)] = [[r[j]] for r in res]
    for s in scorers:
        if isinstance(s, VideoScorer):
            why = s.not_applicable(geom.height, geom.width)
            if why:
                by_scorer[id(s)] = [[MetricScore(s.name, s.spec.direction, None, note=why)]
                                    for _ in tsrcs]
                continue
            t0 = time.perf_counter()
            out = s.score_video(rsrc, tsrcs, progress=progress)
            sec = (time.perf_counter() - t0) / max(len(tsrcs), 1)
            for per_test in out:
                for m in per_test:
                    m.extra.setdefault("seconds", sec)
            by_scorer[id(s)] = out
    out = [[m for s in scorers for m in by_scorer[id(s)][i]] for i in range(len(tsrcs))]
    for t, per_test in zip(tsrcs, out, strict=True):
        note = alignment_note(rsrc, t)
        for m in per_test:
            if note and m.score is not None:  # a metric that does not apply keeps its reason
                m.note = f"{m.note}; {note}" if m.note else note
    return out
