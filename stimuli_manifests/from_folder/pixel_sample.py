"""The same few pixels of a few frames of every video, kept while init decodes it, so that
test videos can be compared with their reference without a second decode.

Six frames spread over the video and, in each, every ``stride``-th pixel in both directions
(about 32k pixels a frame, so a 4K video keeps about 0.6 MB). A strided subset, not a
downscale: it keeps the pixels' own values, so the mean squared difference over it
estimates the full frames' without the averaging that would hide noise and aliasing."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SAMPLED_FRAMES = 6
TARGET_PIXELS = 32_768


def sampled_frames(frame_count: int) -> tuple[int, ...]:
    """The frame indices sampled: spread evenly from the first to the last frame."""
    if frame_count <= 0:
        return ()
    k = min(SAMPLED_FRAMES, frame_count)
    return tuple(sorted({round(j * (frame_count - 1) / max(k - 1, 1)) for j in range(k)}))


def stride_for(height: int, width: int) -> int:
    """Every how many pixels one is kept, for about :data:`TARGET_PIXELS` a frame."""
    return max(1, math.ceil(math.sqrt(height * width / TARGET_PIXELS)))


@dataclass(frozen=True)
class PixelSample:
    """The kept pixels: (frames, rows, columns, 3) uint8, and where they come from."""

    frames: tuple[int, ...]
    stride: int
    shape: tuple[int, int]
    pixels: np.ndarray


class SampleCollector:
    """Fed every decoded frame in order; keeps the sampled ones' strided pixels."""

    def __init__(self, frame_count: int) -> None:
        self.wanted = sampled_frames(frame_count)
        self.kept: list[np.ndarray] = []
        self.shape: tuple[int, int] | None = None

    def add(self, index: int, frame: np.ndarray) -> None:
        if index not in self.wanted:
            return
        self.shape = self.shape or (int(frame.shape[0]), int(frame.shape[1]))
        step = stride_for(*self.shape)
        self.kept.append(np.ascontiguousarray(frame[::step, ::step, :3]))

    def sample(self) -> PixelSample | None:
        """None when not every sampled frame came (the file decoded short)."""
        if self.shape is None or len(self.kept) != len(self.wanted):
            return None
        return PixelSample(self.wanted, stride_for(*self.shape), self.shape,
                           np.stack(self.kept))


def mean_squared_difference(a: PixelSample, b: PixelSample) -> float | None:
    """Over the kept pixels, in 8-bit code values squared; None when the two videos' frame
    counts or sizes differ (their samples are not of the same places)."""
    if a.frames != b.frames or a.shape != b.shape:
        return None
    diff = a.pixels.astype(np.float64) - b.pixels.astype(np.float64)
    return float(np.mean(diff * diff))
