"""Probing a researcher's videos: what each is, whether it decodes, and how fast.

Every file is decoded in full through the same reader the player uses, so a file that breaks
half-way is found now rather than in a participant's trial, and the measured decode speed
says whether the player's background decoding keeps up (see ``study_app.preflight``).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import av
from tqdm import tqdm

from ..checksums import sha256_file
from ..errors import StimuliError, UnshowableVideoError
from ..video import VideoInfo, VideoSource
from .pixel_sample import PixelSample, SampleCollector
from .timing import decoder_errors, uneven_timing

# FFmpeg's color_trc values of the HDR transfer functions
_HDR_TRANSFERS = {16: "PQ transfer, SMPTE ST 2084", 18: "HLG transfer, ARIB STD-B67"}


def container_warnings(path: Path, fps: float) -> tuple[list[str], int]:
    """What the container says that decoded frames do not (one open of the file): uneven
    timestamps, further video streams, an HDR transfer function; and the frame slots its
    timestamps skip (:class:`~.timing.TimestampCheck`)."""
    warnings: list[str] = []
    try:
        with av.open(str(path)) as container:
            streams = container.streams.video
            count = len(streams)
            trc = streams[0].codec_context.color_trc if streams else None
            timing = uneven_timing(container)
    except (av.error.FFmpegError, AttributeError):
        return warnings, 0
    if (gap := timing.uneven) is not None:
        warnings.append(f"{gap}; the player and the metrics show every frame for "
                        f"1/{fps:g} s, so the file's own timing is not reproduced")
    if count > 1:
        warnings.append(f"{count} video streams; only the first is shown and scored")
    if (hdr := _HDR_TRANSFERS.get(int(trc or 0))) is not None:
        warnings.append(f"HDR video ({hdr}); the player and the metrics show its code values "
                        "as SDR RGB without tone mapping, so it looks washed out: export SDR "
                        "(BT.709) renders for the study")
    return warnings, timing.skipped_slots


@dataclass(frozen=True)
class ProbedVideo:
    """One file as probed: its info (None when it cannot be read), checksum and decode speed."""

    path: Path
    sha256: str
    size_bytes: int
    info: VideoInfo | None = None
    decode_seconds: float = 0.0
    error: str | None = None
    warnings: tuple[str, ...] = ()
    error_kind: str = "undecodable"
    skipped_slots: int = 0
    """Frame slots its timestamps skip (a dropped frame): a test that skips where its
    reference does not is out of step with it."""
    sample: PixelSample | None = field(default=None, compare=False, repr=False)
    """A few of its pixels, to compare a test with its reference (:mod:`.pixel_sample`)."""

    @property
    def decode_fps(self) -> float:
        """Frames decoded per second on this machine (0 when it did not decode)."""
        if self.info is None or self.decode_seconds <= 0:
            return 0.0
        return self.info.frame_count / self.decode_seconds


@dataclass(frozen=True)
class DecodeFindings:
    """What decoding one file in full says: its info (None when it cannot be read), how long
    the decode took, the reason it is unusable, and what only deserves a warning."""

    info: VideoInfo | None
    decode_seconds: float = 0.0
    error: str | None = None
    warnings: tuple[str, ...] = ()
    error_kind: str = "undecodable"
    """What ``error`` is: 'undecodable', or 'not as stored' (it decodes, but media players
    show it otherwise than the toolkit would)."""
    skipped_slots: int = 0
    sample: PixelSample | None = field(default=None, compare=False, repr=False)


def decode_findings(path: Path) -> DecodeFindings:
    """Decode one file in full; problems land in ``error``, never raise.

    The player and the metrics take the container's frame count as the video's length, so
    a file that decodes fewer (or more) frames is damaged for them, and FFmpeg's own error
    messages while decoding (a bad checksum, a broken slice) mean frames that decode to the
    wrong pixels without failing."""
    try:
        source = VideoSource(path, on_conversion="quiet")  # init's table reports it
        with decoder_errors() as errors:
            collector = SampleCollector(source.info.frame_count)
            start = time.perf_counter()
            count = 0
            for frame in source.frames():
                collector.add(count, frame)
                count += 1
            seconds = time.perf_counter() - start
    except UnshowableVideoError as exc:
        return DecodeFindings(None, error=str(exc).removeprefix(f"{path}: "),
                              error_kind="not as stored")
    except StimuliError as exc:
        message = str(exc).removeprefix(f"{path}: ")
        return DecodeFindings(None, error=f"cannot be decoded: {message}")
    info = source.info
    if count != info.frame_count:
        return DecodeFindings(None, error=(
            f"truncated or damaged: its container lists {info.frame_count} frames but "
            f"{count} decode"
            + (" (or it was cut without re-encoding, and its edit list hides frames the "
               "container still holds)" if count < info.frame_count else "")
            + "; re-export or re-encode it"))
    if errors:
        return DecodeFindings(None, error=(
            f"damaged: the decoder reported {errors[0]}"
            + (f" and {len(errors) - 1} more error(s)" if len(errors) > 1 else "")
            + "; frames may show wrong pixels: re-export or re-encode it"))
    warnings, skipped = container_warnings(path, info.fps) if info.kind == "video" else ([], 0)
    return DecodeFindings(info, seconds, warnings=tuple(warnings), skipped_slots=skipped,
                          sample=collector.sample())


def probe_file(path: Path) -> ProbedVideo:
    """Checksum and fully decode one file (:func:`decode_findings`); never raises."""
    sha = sha256_file(path)
    size = path.stat().st_size
    found = decode_findings(path)
    return ProbedVideo(path, sha, size, found.info, found.decode_seconds, found.error,
                       found.warnings, found.error_kind, found.skipped_slots, found.sample)


def probe_files(paths: Iterable[Path], *, progress: bool = False,
                desc: str = "probing videos") -> dict[Path, ProbedVideo]:
    """Probe every file (in order), with a progress bar on request."""
    paths = list(paths)
    return {path: probe_file(path)
            for path in tqdm(paths, desc=desc, unit="video", disable=not progress)}
