"""Videos written in tests with PyAV directly, for what ``write_video`` deliberately does not
write: lossy codecs, high bit depths, uneven timestamps, display matrices, odd containers."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import numpy as np


def encode(path: Path, frames: np.ndarray, *, codec: str = "ffv1", pix_fmt: str = "bgr0",
           rate: int | Fraction = 30, options: dict[str, str] | None = None,
           pts: Sequence[int] | None = None, time_base: Fraction | None = None,
           container_options: dict[str, str] | None = None,
           setup: Callable[[Any], None] | None = None) -> Path:
    """Encode (T, H, W, 3) uint8 RGB ``frames`` to ``path``: frame i at ``pts[i]`` in
    ``time_base`` (default i at 1/rate); ``setup(stream)`` runs before the first frame (a
    display matrix, a pixel aspect ratio). Frames are converted to ``pix_fmt`` by FFmpeg."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w", options=container_options or {}) as container:
        stream = container.add_stream(codec, rate=rate)
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], pix_fmt
        if options:
            stream.options = options
        if time_base is not None:
            stream.time_base = time_base
        if setup is not None:
            setup(stream)
        for i, frame in enumerate(frames):
            vf = av.VideoFrame.from_ndarray(frame, format="rgb24")  # PyAV converts it
            vf.pts = i if pts is None else pts[i]
            if time_base is not None:
                vf.time_base = time_base
            for packet in stream.encode(vf):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path
