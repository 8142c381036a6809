"""Error maps: recording them, and showing them as a heat-map video over the test video.

The visualisation follows the authors' (itself from FovVideoVDP): error / 100 clamped to
[0, 1], a five-stop blue-cyan-green-yellow-red colour map at 0, .25, .5, .75, 1 (colours
divided by their luminance), multiplied by a histogram tone-mapping of the test video's log
luminance (fitted over the whole video in two streaming passes). Their shortcut for
low-contrast videos adds 1e03 where 1e-3 was meant; here it is done as intended. The heat map
has the reference's size and frame count (the grid the metric scored on).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING

import av
import numpy as np
import torch

from .errors import CGVQMError

if TYPE_CHECKING:
    from .stream import FrameSource, Geometry

log = logging.getLogger(__name__)

SCALE = 100.0  # error that maps to the top of the colour map
STOPS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
COLOURS = np.array([[0.2, 0.2, 1.0], [0.2, 1.0, 1.0], [0.2, 1.0, 0.2], [1.0, 1.0, 0.2],
                    [1.0, 0.2, 0.2]])
LUMA = np.array([0.212656, 0.715158, 0.072186])
DYNAMIC_RANGE, BINS, T_EXP = 0.6, 1024, 3.0


class EmapRecorder:
    """Collects the per-clip maps of one test video into a (frames, H, W) array."""

    def __init__(self, geom: Geometry) -> None:
        self.map = np.zeros((geom.frames, geom.height, geom.width), np.float32)
        self.clip_len = geom.clip_len

    def __call__(self, clip: int, emap: np.ndarray, frames: np.ndarray) -> None:
        start = clip * self.clip_len
        self.map[start: start + emap.shape[0]] = emap

    def array(self) -> np.ndarray:
        return self.map


def _luminance(frames: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(frames.astype(np.float32) @ LUMA.astype(np.float32))


@dataclass
class ToneCurve:
    """Maps log luminance (of 0..255 RGB) to display brightness in [0.2, 0.8]."""

    clampval: float
    b_min: float
    b_max: float
    curve: np.ndarray | None  # None: low-contrast video, linear mapping

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        b = np.log(np.maximum(_luminance(frames).numpy(), self.clampval))
        lo = (1 - DYNAMIC_RANGE) / 2
        if self.curve is None:
            return (b - self.b_min) / (self.b_max - self.b_min + 1e-3) * DYNAMIC_RANGE + lo
        scale = np.linspace(self.b_min, self.b_max, BINS)
        return np.interp(b, scale, self.curve)


def fit_tone_curve(test: FrameSource, geom: Geometry) -> ToneCurve:
    """Two passes over the (aligned) test video: luminance range, then its histogram."""
    from .stream import aligned_frames

    pos_min, y_max = np.inf, 0.0
    for f in aligned_frames(test, geom):
        y = _luminance(f)
        pos = y[y > 0]
        if pos.numel():
            pos_min = min(pos_min, float(pos.min()))
        y_max = max(y_max, float(y.max()))
    clampval = pos_min if np.isfinite(pos_min) else 1.0
    b_min, b_max = float(np.log(clampval)), float(np.log(max(y_max, clampval)))
    if b_max - b_min < DYNAMIC_RANGE:
        return ToneCurve(clampval, b_min, b_max, None)
    hist = torch.zeros(BINS, dtype=torch.float64)
    for f in aligned_frames(test, geom):
        b = torch.log(torch.clamp(_luminance(f), min=clampval))
        hist += torch.histc(b, BINS, b_min, b_max).double()
    p = (hist / hist.sum()).numpy()
    dy = p ** (1.0 / T_EXP)
    dy = dy / dy.sum()
    curve = np.cumsum(dy) * DYNAMIC_RANGE + (1 - DYNAMIC_RANGE) / 2
    return ToneCurve(clampval, b_min, b_max, curve)


def colourise(emap: np.ndarray, tone: np.ndarray) -> np.ndarray:
    """(t, H, W) errors and tone-mapped brightness -> (t, H, W, 3) uint8 heat map."""
    x = np.clip(emap / SCALE, 0.0, 1.0)
    chroma = COLOURS / (COLOURS @ LUMA + 1e-4)[:, None]
    out = np.stack([np.interp(x, STOPS, chroma[:, c]) for c in range(3)], axis=-1)
    out = np.clip(out * tone[..., None], 0.0, 1.0)
    return (out * 255).astype(np.uint8)


class EmapVideoWriter:
    """Writes heat-map frames as they are produced: a video (.mp4 H.264, or lossless .mkv)
    and/or one PNG per frame."""

    def __init__(self, path: str | Path | None, png_dir: str | Path | None, fps: float,
                 tone: ToneCurve) -> None:
        self.tone = tone
        self.count = 0
        self.png_dir = Path(png_dir) if png_dir else None
        if self.png_dir:
            self.png_dir.mkdir(parents=True, exist_ok=True)
        self.container = self.stream = None
        self.path = Path(path) if path else None
        if self.path is not None:
            suffix = self.path.suffix.lower()
            if suffix not in (".mp4", ".mkv"):
                raise CGVQMError(f"{self.path}: error-map videos are written as .mp4 (H.264) "
                                 "or .mkv (lossless); choose one of these names")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.lossless = suffix == ".mkv"
            try:
                self.container = av.open(str(self.path), mode="w")
            except (av.error.FFmpegError, OSError) as exc:
                raise CGVQMError(f"{self.path}: cannot write ({exc})") from None
            rate = Fraction(fps).limit_denominator(1001)
            if self.lossless:
                self.stream = self.container.add_stream("libx264rgb", rate=rate)
                self.stream.pix_fmt = "rgb24"
                self.stream.options = {"qp": "0"}
            else:
                self.stream = self.container.add_stream("libx264", rate=rate)
                self.stream.pix_fmt = "yuv420p"
                self.stream.options = {"crf": "20"}

    def __call__(self, clip: int, emap: np.ndarray, frames: np.ndarray) -> None:
        rgb = colourise(emap, self.tone(frames))
        for frame in rgb:
            if self.png_dir is not None:
                from PIL import Image

                Image.fromarray(frame).save(self.png_dir / f"{self.count:06d}.png")
            if self.stream is not None:
                if not self.lossless and (frame.shape[0] % 2 or frame.shape[1] % 2):
                    frame = np.pad(frame, ((0, frame.shape[0] % 2), (0, frame.shape[1] % 2),
                                           (0, 0)), mode="edge")
                if self.count == 0:
                    self.stream.width, self.stream.height = frame.shape[1], frame.shape[0]
                vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
                vf.pts = self.count
                for pkt in self.stream.encode(vf):
                    self.container.mux(pkt)
            self.count += 1

    def close(self) -> None:
        if self.container is not None:
            for pkt in self.stream.encode():
                self.container.mux(pkt)
            self.container.close()
            self.container = None
