"""Decoding a trial's stimulus pair off the presentation path, with background prefetch.

The next trial's pair is decoded in a worker thread (PyAV releases the GIL while decoding)
while the participant rates; the GL upload then happens on the main thread before the
trial's first frame. Nothing is decoded while a video is on screen.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from session_store.errors import StudyError
from stimuli_manifests import StimuliError, probe_video, read_video

log = logging.getLogger(__name__)


@dataclass
class DecodedPair:
    """Both videos of a trial as (T, H, W, 3) uint8, with their frame rate."""

    stimulus: str
    test: np.ndarray
    reference: np.ndarray
    fps: float
    seconds: float

    @property
    def nbytes(self) -> int:
        return self.test.nbytes + self.reference.nbytes


def decode_pair(stimulus: str, test_path: Path, reference_path: Path) -> DecodedPair:
    """Decode both videos fully; their sizes and frame counts must match."""
    t0 = time.perf_counter()
    try:
        fps = probe_video(test_path).fps
        test = read_video(test_path)
        ref = test if test_path == reference_path else read_video(reference_path)
    except StimuliError as exc:
        raise StudyError(f"cannot decode stimulus {stimulus}: {exc}; run 'cgvq-study check' "
                         "on the study folder") from None
    if test.shape != ref.shape:
        raise StudyError(
            f"stimulus {stimulus} ({test.shape[2]}x{test.shape[1]}, {test.shape[0]} frames) and "
            f"its reference ({ref.shape[2]}x{ref.shape[1]}, {ref.shape[0]} frames) differ; "
            "run 'cgvq-study check' on the study folder")
    return DecodedPair(stimulus, test, ref, fps, time.perf_counter() - t0)


def pair_bytes(width: int, height: int, frames: int) -> int:
    """Memory of one decoded pair of RGB videos."""
    return 2 * width * height * 3 * frames


class Prefetcher:
    """One background decode at a time, keyed by plan index."""

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="prefetch")
        self._jobs: dict[int, Future[DecodedPair]] = {}

    def start(self, key: int, stimulus: str, test: Path, reference: Path) -> None:
        if key not in self._jobs:
            self._jobs[key] = self._pool.submit(decode_pair, stimulus, test, reference)

    def ready(self, key: int) -> bool:
        job = self._jobs.get(key)
        return job is not None and job.done()

    def take(self, key: int) -> DecodedPair | None:
        """The decoded pair (waits for it), or None when it was never started."""
        job = self._jobs.pop(key, None)
        if job is None:
            return None
        # Drop any other (stale) job results so their memory is freed.
        for other in list(self._jobs):
            self._jobs.pop(other).cancel()
        return job.result()

    def close(self) -> None:
        for job in self._jobs.values():
            job.cancel()
        self._jobs.clear()
        self._pool.shutdown(wait=False, cancel_futures=True)
