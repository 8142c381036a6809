"""Decode speed of the lossless codecs a study's videos can be stored in, at 1024x1024 60 fps.

The player decodes a whole test/reference pair into memory while the participant rates the
previous trial, and its pre-flight refuses a computer that needs more than
``study_app.preflight.MAX_PAIR_DECODE_S`` seconds per pair. This benchmark writes the same
procedural CG-like clip (smooth shading, a moving checker texture, and render noise at two
strengths: a clean render and a noisy path-traced one) with every codec of
:mod:`stimuli_manifests.lossless` and, for comparison, a visually lossless H.264 (what
researchers often bring), then decodes it through the player's own reader
(``stimuli_manifests.read_video``, all cores) and with one decoding thread (a participant's
busy or small CPU). It prints frames per second, the seconds one 3 s pair takes, the margin
against real time, and the size per second of video; ``cgvq-study init --transcode`` writes
the codec that decodes fastest (``stimuli_manifests.lossless.PLAYER_CODEC``).

    .venv/bin/python benchmarks/bench_decode.py [--size 1024] [--fps 60] [--seconds 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from stimuli_manifests import read_video, write_video  # noqa: E402
from stimuli_manifests.lossless import LOSSLESS_CODECS, PLAYER_CODEC, codec_spec  # noqa: E402
from study_app.preflight import MAX_PAIR_DECODE_S  # noqa: E402

PAIR_SECONDS = 3.0  # the paper's stimuli are 3 s long


def cg_clip(size: int, frames: int, noise: float, seed: int = 0) -> np.ndarray:
    """A moving shaded pattern with a checker texture and Gaussian render noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(np.float32)
    out = np.empty((frames, size, size, 3), np.uint8)
    for t in range(frames):
        base = 0.5 + 0.5 * np.sin((x + 4 * t) / 37.0) * np.cos((y - 2 * t) / 53.0)
        checker = ((x // 16 + y // 16 + t // 4) % 2) * 0.2
        img = np.stack([base, 0.8 * base + checker, 1.0 - 0.6 * base], axis=-1)
        if noise:
            img += rng.normal(0.0, noise, img.shape).astype(np.float32)
        out[t] = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return out


def write_h264(path: Path, frames: np.ndarray, fps: int) -> Path:
    """Visually lossless 4:2:0 H.264 (crf 18): a typical 'final render' a researcher has."""
    with av.open(str(path), "w", format="matroska") as container:
        stream = container.add_stream("libx264", rate=Fraction(fps))
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": "18", "preset": "medium"}
        stream.width, stream.height = frames.shape[2], frames.shape[1]
        for i, frame in enumerate(frames):
            vf = av.VideoFrame.from_ndarray(frame, format="rgb24")
            vf.pts = i
            for packet in stream.encode(vf):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def decode_fps_one_thread(path: Path) -> float:
    """Frames per second decoding to RGB with a single decoder thread."""
    start = time.perf_counter()
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        stream.thread_count = 1
        n = sum(1 for frame in container.decode(stream) if frame.to_ndarray(format="rgb24")
                is not None)
    return n / (time.perf_counter() - start)


def decode_fps_player(path: Path, repeats: int) -> tuple[float, np.ndarray]:
    """Best of ``repeats`` full decodes through the player's reader (all cores)."""
    best = float("inf")
    frames = np.empty(0)
    for _ in range(repeats):
        start = time.perf_counter()
        frames = read_video(path)
        best = min(best, time.perf_counter() - start)
    return len(frames) / best, frames


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=1024, help="frame width and height")
    parser.add_argument("--fps", type=int, default=60)
    parser.add_argument("--seconds", type=float, default=2.0, help="length of the test clip")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    n_frames = max(1, round(args.seconds * args.fps))
    pair_frames = 2 * PAIR_SECONDS * args.fps
    print(f"{args.size}x{args.size}, {args.fps} fps, {n_frames} frames per clip; "
          f"{os.cpu_count()} CPU cores; PyAV {av.__version__}, FFmpeg "
          f"{av.ffmpeg_version_info}")
    print(f"pair = test + reference of {PAIR_SECONDS:g} s = {pair_frames:g} frames; the "
          f"pre-flight allows {MAX_PAIR_DECODE_S:g} s per pair; real time needs "
          f"{args.fps} fps\n")
    header = (f"{'content':8} {'codec':9} {'MiB/s':>7} {'fps all':>8} {'fps 1 thr':>9} "
              f"{'pair s (all)':>12} {'pair s (1 thr)':>14} {'x real time':>11}  exact")
    print(header)
    print("-" * len(header))
    with tempfile.TemporaryDirectory(prefix="bench_decode_") as tmp:
        for content, noise in (("clean", 0.004), ("noisy", 0.03)):
            clip = cg_clip(args.size, n_frames, noise)
            rows = [(name, codec_spec(name).suffix) for name in LOSSLESS_CODECS]
            rows.append(("h264-crf18", ".mkv"))
            for name, suffix in rows:
                path = Path(tmp) / f"{content}_{name}{suffix}"
                if name == "h264-crf18":
                    write_h264(path, clip, args.fps)
                else:
                    write_video(path, clip, args.fps, codec=name)  # type: ignore[arg-type]
                fps_all, decoded = decode_fps_player(path, args.repeats)
                fps_one = decode_fps_one_thread(path)
                exact = "yes" if np.array_equal(decoded, clip) else "no (lossy)"
                mib_s = path.stat().st_size / 2**20 / args.seconds
                print(f"{content:8} {name:9} {mib_s:7.1f} {fps_all:8.1f} {fps_one:9.1f} "
                      f"{pair_frames / fps_all:12.2f} {pair_frames / fps_one:14.2f} "
                      f"{fps_one / args.fps:11.2f}  {exact}", flush=True)
                path.unlink()
    print(f"\ncgvq-study init --transcode writes {PLAYER_CODEC} "
          f"({LOSSLESS_CODECS[PLAYER_CODEC].summary})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
