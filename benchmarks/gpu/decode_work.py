"""Decoding one video to RGB frames, importable by a worker process (numpy, PyAV and the
project's reader only: a spawned worker should not pay for importing torch)."""

from __future__ import annotations

import time


def decode(path: str) -> float:
    """Seconds to decode ``path`` to RGB with the reader cgvqm_core uses."""
    from stimuli_manifests import open_video

    t0 = time.perf_counter()
    for _ in open_video(path).frames():
        pass
    return time.perf_counter() - t0
