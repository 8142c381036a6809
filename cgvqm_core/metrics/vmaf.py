"""VMAF (Li et al. 2016), when an ``ffmpeg`` built with libvmaf is on PATH.

Frames stream from the project's video source (aligned like every other metric) into ffmpeg
as raw RGB through two pipes; ffmpeg's ``libvmaf`` filter reports the pooled mean VMAF and
per-frame scores (higher is better, 0..100). Without such an ffmpeg it is unavailable.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from ..errors import CGVQMError
from ..stream import FrameSource, Geometry, _counted, aligned_frames
from .registry import (
    HIGHER,
    VIDEO,
    VIDEO_METRICS,
    Availability,
    Entry,
    MetricOptions,
    MetricScore,
    MetricSpec,
    VideoScorer,
)

SPEC = MetricSpec(
    name="vmaf", title="VMAF", family="vmaf", direction=HIGHER, value_range=(0, 100),
    kind=VIDEO, colour="frames converted by ffmpeg from RGB to YUV 4:4:4 (BT.601) for libvmaf",
    licence="libvmaf: BSD-2-Clause-Patent (Netflix); ffmpeg: LGPL/GPL", reference="Li et al. "
    "2016", devices=("cpu",), min_size=16)


@functools.cache
def ffmpeg_with_vmaf() -> str | None:
    exe = shutil.which("ffmpeg")
    if exe is None:
        return None
    try:
        out = subprocess.run([exe, "-hide_banner", "-filters"], capture_output=True, text=True,
                             timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return exe if "libvmaf" in out else None


def _feed(fd: int, frames: Iterator[Any]) -> None:
    with os.fdopen(fd, "wb") as fh:
        try:
            for f in frames:
                fh.write(memoryview(f).cast("B"))
        except BrokenPipeError:
            pass


class VmafScorer(VideoScorer):
    spec = SPEC

    def __init__(self, options: MetricOptions) -> None:
        self.exe = ffmpeg_with_vmaf()
        if self.exe is None:
            raise CGVQMError("VMAF needs an ffmpeg built with libvmaf on PATH")

    def settings(self) -> dict[str, Any]:
        return {"model": "libvmaf default", "pool": "mean"}

    def score_video(self, ref: FrameSource, tests: Sequence[FrameSource], *,
                    progress: bool = False) -> list[list[MetricScore]]:
        info = ref.info
        geom = Geometry(int(info.frame_count), int(info.height), int(info.width),
                        float(info.fps), 1)
        return [[self._one(ref, t, geom)] for t in tests]

    def _one(self, ref: FrameSource, test: FrameSource, geom: Geometry) -> MetricScore:
        size = f"{geom.width}x{geom.height}"
        raw = ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", size, "-r", f"{geom.fps:g}"]
        with tempfile.TemporaryDirectory() as tmp:
            log = Path(tmp) / "vmaf.json"
            r_read, r_write = os.pipe()
            t_read, t_write = os.pipe()
            cmd = [self.exe, "-hide_banner", "-loglevel", "error", *raw, "-i",
                   f"pipe:{t_read}", *raw, "-i", f"pipe:{r_read}", "-lavfi",
                   f"[0:v]format=yuv444p[d];[1:v]format=yuv444p[r];[d][r]libvmaf="
                   f"log_fmt=json:log_path={log}", "-f", "null", "-"]
            proc = subprocess.Popen(cmd, pass_fds=(t_read, r_read), stderr=subprocess.PIPE)
            os.close(t_read)
            os.close(r_read)
            feeders = [threading.Thread(target=_feed, args=(t_write, aligned_frames(test, geom))),
                       threading.Thread(target=_feed, args=(r_write, _counted(ref, "reference")))]
            for th in feeders:
                th.start()
            for th in feeders:
                th.join()
            _, err = proc.communicate()
            if proc.returncode != 0:
                raise CGVQMError(f"ffmpeg/libvmaf failed: {err.decode(errors='replace')[-300:]}")
            doc = json.loads(log.read_text())
        frames = [float(f["metrics"]["vmaf"]) for f in doc.get("frames", [])]
        pooled = doc.get("pooled_metrics", {}).get("vmaf", {}).get("mean")
        return MetricScore(SPEC.name, SPEC.direction, float(pooled), per_frame=frames)


class VmafEntry(Entry):
    spec = SPEC

    def availability(self) -> Availability:
        if ffmpeg_with_vmaf() is None:
            return Availability(False, "no ffmpeg built with libvmaf on PATH")
        return Availability(True)

    def build(self, options: MetricOptions) -> VmafScorer:
        return VmafScorer(options)


ENTRIES: tuple[Entry, ...] = (VmafEntry(),)
LISTING_GROUP = VIDEO_METRICS
