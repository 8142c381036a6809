"""Reading and writing stimulus videos as uint8 RGB frames.

One abstraction, :class:`VideoSource`, streams frames from any supported input so that no
caller needs to hold a whole video in memory: video files through PyAV (FFmpeg), folders of
PNG frames, and ``.npy`` arrays of shape (T, H, W, 3). Generated stimuli are written
losslessly (FFV1 or x264 in RGB mode, in Matroska) so that decoding returns exactly the frames
that were written.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Literal

import av
import numpy as np

from .errors import UnshowableVideoError, VideoError
from .frame_files import ordered_frames
from .lossless import LosslessCodec, codec_spec

log = logging.getLogger(__name__)

DEFAULT_FOLDER_FPS = 30.0
ConversionPolicy = Literal["warn", "error", "quiet"]
SourceKind = Literal["video", "frames", "npy"]


@dataclass(frozen=True)
class VideoInfo:
    """What a probe tells about a video without decoding it."""

    path: Path
    kind: SourceKind
    width: int
    height: int
    fps: float
    frame_count: int
    pix_fmt: str
    codec: str
    bit_depth: int
    has_alpha: bool
    profile: str | None = None  # the codec's profile, e.g. H.264's "High 4:4:4 Predictive"

    @property
    def duration(self) -> float:
        """Length in seconds (frame_count / fps)."""
        return self.frame_count / self.fps

    @property
    def needs_conversion(self) -> bool:
        """True when decoding to 8-bit RGB loses information (high bit depth or alpha)."""
        return self.bit_depth > 8 or self.has_alpha


def _pix_fmt_traits(pix_fmt: str) -> tuple[int, bool]:
    """(bits per component, has alpha) of an FFmpeg pixel format name."""
    try:
        desc = av.VideoFormat(pix_fmt)
    except (ValueError, TypeError):
        return 8, False
    bits = max((c.bits for c in desc.components), default=8)
    has_alpha = any(c.is_alpha for c in desc.components) if desc.components else False
    # 'bgr0'/'rgb0' have a padding byte that FFmpeg does not flag as alpha: fine either way.
    return bits, has_alpha


class VideoSource:
    """A video that can be probed and streamed as uint8 RGB frames (H, W, 3).

    ``fps`` overrides the frame rate of frame folders and .npy arrays (which carry none; the
    default is 30). ``on_conversion`` decides what happens with 10/12/16-bit or alpha input:
    ``"warn"`` converts to 8-bit RGB and logs a warning, ``"error"`` raises :class:`VideoError`,
    ``"quiet"`` converts without a word (for callers that report it themselves).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        fps: float | None = None,
        on_conversion: ConversionPolicy = "warn",
    ) -> None:
        self.path = Path(path)
        self._fps_override = fps
        self.on_conversion = on_conversion
        if fps is not None and not fps > 0:
            raise VideoError(f"{self.path}: fps must be positive, got {fps}")
        if not self.path.exists():
            raise VideoError(f"{self.path}: no such file or folder")
        if self.path.is_dir():
            self._frame_files = ordered_frames(self.path)
            self.info = self._probe_folder()
        elif self.path.suffix.lower() == ".npy":
            self.info = self._probe_npy()
        else:
            self.info = self._probe_container()
        self._check_conversion()

    # -- probing ------------------------------------------------------------------------
    def _probe_container(self) -> VideoInfo:
        container = _open_container(self.path)
        try:
            if not container.streams.video:
                raise VideoError(f"{self.path}: contains no video stream")
            stream = container.streams.video[0]
            ctx = stream.codec_context
            frames = stream.frames
            if not frames:
                try:
                    frames = sum(1 for pkt in container.demux(stream) if pkt.size > 0)
                except av.error.FFmpegError as exc:
                    raise VideoError(f"{self.path}: corrupt video ({exc})") from None
            rate = _frame_rate(stream, frames)
            if self._fps_override is not None:
                fps = float(self._fps_override)
            elif rate:
                fps = float(rate)
            else:
                raise VideoError(f"{self.path}: frame rate unknown; pass fps explicitly")
            width, height = ctx.width, ctx.height
            pix_fmt = ctx.pix_fmt or "unknown"
            codec = ctx.name
            profile = ctx.profile
            _refuse_non_square_pixels(self.path, stream)
        finally:
            container.close()
        _refuse_display_rotation(self.path)
        if frames == 0:
            raise VideoError(f"{self.path}: the video has no frames")
        if not width or not height:
            raise VideoError(f"{self.path}: frame size unknown (corrupt or unsupported video)")
        bits, alpha = _pix_fmt_traits(pix_fmt)
        return VideoInfo(
            self.path, "video", width, height, fps, int(frames), pix_fmt, codec, bits, alpha,
            profile,
        )

    def _probe_folder(self) -> VideoInfo:
        from PIL import Image

        if not self._frame_files:
            raise VideoError(f"{self.path}: folder holds no .png frames")
        try:
            with Image.open(self._frame_files[0]) as img:
                width, height, mode = img.width, img.height, img.mode
        except OSError as exc:
            raise VideoError(f"{self._frame_files[0]}: not a readable PNG ({exc})") from None
        bits = 16 if mode in ("I;16", "I;16B", "I", "RGB;16", "RGBA;16") else 8
        fps = float(self._fps_override or DEFAULT_FOLDER_FPS)
        return VideoInfo(
            self.path,
            "frames",
            width,
            height,
            fps,
            len(self._frame_files),
            mode,
            "png",
            bits,
            "A" in mode,
        )

    def _probe_npy(self) -> VideoInfo:
        try:
            arr = np.load(self.path, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise VideoError(f"{self.path}: not a readable .npy array ({exc})") from None
        if arr.ndim != 4 or arr.shape[-1] not in (3, 4):
            raise VideoError(
                f"{self.path}: array shape {arr.shape} is not (frames, height, width, 3)"
            )
        if arr.dtype == np.uint16:
            bits = 16
            _refuse_low_bit_samples(self.path, arr)
        elif arr.dtype == np.uint8:
            bits = 8
        else:
            raise VideoError(
                f"{self.path}: array dtype {arr.dtype} is not supported; save uint8 RGB "
                "(0..255) frames of shape (frames, height, width, 3)"
            )
        if arr.shape[0] == 0:
            raise VideoError(f"{self.path}: the array has no frames")
        fps = float(self._fps_override or DEFAULT_FOLDER_FPS)
        return VideoInfo(
            self.path,
            "npy",
            int(arr.shape[2]),
            int(arr.shape[1]),
            fps,
            int(arr.shape[0]),
            f"{arr.dtype}x{arr.shape[-1]}",
            "npy",
            bits,
            arr.shape[-1] == 4,
        )

    def _check_conversion(self) -> None:
        info = self.info
        if not info.needs_conversion:
            return
        what = []
        if info.bit_depth > 8:
            what.append(f"{info.bit_depth}-bit")
        if info.has_alpha:
            what.append("alpha channel")
        desc = " and ".join(what)
        if self.on_conversion == "error":
            raise VideoError(
                f"{self.path}: input has {desc} ({info.pix_fmt}); the toolkit works on 8-bit "
                "RGB: convert it first or allow the conversion (cgvqm --allow-convert)"
            )
        if self.on_conversion == "warn":
            log.warning("%s: %s input (%s) converted to 8-bit RGB", self.path, desc,
                        info.pix_fmt)

    # -- decoding -----------------------------------------------------------------------
    def frames(self) -> Iterator[np.ndarray]:
        """Yield every frame in order as a (H, W, 3) uint8 array."""
        if self.info.kind == "frames":
            yield from self._folder_frames()
        elif self.info.kind == "npy":
            yield from self._npy_frames()
        else:
            yield from self._container_frames()

    def _container_frames(self) -> Iterator[np.ndarray]:
        container = _open_container(self.path)
        try:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            count = 0
            try:
                for frame in container.decode(stream):
                    arr = frame.to_ndarray(format="rgb24")
                    if arr.shape[:2] != (self.info.height, self.info.width):
                        raise VideoError(
                            f"{self.path}: frame {count} is {arr.shape[1]}x{arr.shape[0]}, "
                            f"expected {self.info.width}x{self.info.height} (size changes "
                            "mid-stream are not supported)"
                        )
                    count += 1
                    yield arr
            except av.error.FFmpegError as exc:
                raise VideoError(f"{self.path}: corrupt video at frame {count} ({exc})") from None
            if count == 0:
                raise VideoError(f"{self.path}: no frame could be decoded")
        finally:
            container.close()

    def _folder_frames(self) -> Iterator[np.ndarray]:
        from PIL import Image

        for file in self._frame_files:
            try:
                with Image.open(file) as img:
                    if img.size != (self.info.width, self.info.height):
                        raise VideoError(
                            f"{file}: size {img.width}x{img.height} differs from the first "
                            f"frame's {self.info.width}x{self.info.height}"
                        )
                    if img.mode in ("I;16", "I;16B", "I"):
                        arr16 = np.asarray(img, dtype=np.uint16)
                        arr = (arr16 >> 8).astype(np.uint8)[..., None].repeat(3, axis=-1)
                    else:
                        arr = np.asarray(img.convert("RGB"), dtype=np.uint8)
            except OSError as exc:
                raise VideoError(f"{file}: not a readable PNG ({exc})") from None
            yield arr

    def _npy_frames(self) -> Iterator[np.ndarray]:
        arr = np.load(self.path, mmap_mode="r", allow_pickle=False)
        for frame in arr:
            frame = frame[..., :3]
            if frame.dtype == np.uint16:
                frame = (frame >> 8).astype(np.uint8)
            yield np.array(frame, dtype=np.uint8, copy=True)

    def clips(self, clip_len: int) -> Iterator[np.ndarray]:
        """Yield consecutive clips of ``clip_len`` frames, (n, H, W, 3); the last may be shorter."""
        if clip_len < 1:
            raise VideoError(f"clip length must be at least 1, got {clip_len}")
        buf = np.empty((clip_len, self.info.height, self.info.width, 3), dtype=np.uint8)
        n = 0
        for frame in self.frames():
            buf[n] = frame
            n += 1
            if n == clip_len:
                yield buf.copy()
                n = 0
        if n:
            yield buf[:n].copy()

    def read(self, max_frames: int | None = None) -> np.ndarray:
        """The whole video (or its first ``max_frames``) as (T, H, W, 3) uint8."""
        total = (
            self.info.frame_count if max_frames is None else min(max_frames, self.info.frame_count)
        )
        out = np.empty((total, self.info.height, self.info.width, 3), dtype=np.uint8)
        n = 0
        for frame in self.frames():
            if n == total:
                break
            out[n] = frame
            n += 1
        if n < total:
            log.warning("%s: probe said %d frames, decoded %d", self.path, total, n)
            out = out[:n]
        return out


def _refuse_low_bit_samples(path: Path, arr: np.ndarray) -> None:
    """uint16 frames are read as 16-bit (the high byte kept); 10- or 12-bit samples stored in
    uint16 (values up to 1023 or 4095, as many renderers and decoders write them) would come
    out nearly black, and both videos alike, so every metric would call them identical.
    Judged on the first, middle and last frame (a whole pass would read the whole file)."""
    n = arr.shape[0]
    peak = max(int(arr[i].max()) for i in {0, n // 2, n - 1})
    if 0 < peak <= 4095:
        bits = 10 if peak <= 1023 else 12
        raise VideoError(f"{path}: uint16 values reach only {peak}: {bits}-bit samples? they "
                         f"would read as 16-bit and come out nearly black; scale them to 16 "
                         f"bits (x << {16 - bits}) or convert to uint8 first")


def _refuse_non_square_pixels(path: Path, stream: av.video.stream.VideoStream) -> None:
    """The player shows one stored pixel per screen pixel and the metrics compare stored
    pixels, so an anamorphic video would be seen and scored squeezed."""
    sar = stream.sample_aspect_ratio or stream.codec_context.sample_aspect_ratio
    if sar and sar != 1:
        raise UnshowableVideoError(
            f"{path}: non-square pixels (sample aspect ratio {sar.numerator}:"
            f"{sar.denominator}); re-encode it with square pixels at its display size")


def _refuse_display_rotation(path: Path) -> None:
    """Media players turn or mirror a video by its display matrix (phones and some
    recorders write one); the toolkit shows and scores the stored pixels, so such a video
    would be seen and scored sideways, upside down or mirrored. Read from the first decoded
    frame, where FFmpeg puts the matrix."""
    container = _open_container(path)
    try:
        stream = container.streams.video[0]
        frame = next(container.decode(stream), None)
        turn = _display_turn(frame) if frame is not None else None
    except av.error.FFmpegError:
        return  # decoding reports the damage with the frame it happens at
    finally:
        container.close()
    if turn is not None:
        raise UnshowableVideoError(
            f"{path}: carries a display matrix ({turn}) that media players apply but the "
            "toolkit does not (it shows and scores the stored pixels); re-encode it upright "
            "(FFmpeg applies the matrix when it re-encodes)")


def _display_turn(frame: av.VideoFrame) -> str | None:
    """What the frame's display matrix does ('rotated 90 degrees counter-clockwise',
    'mirrored'), or None when it has none or it is the identity."""
    for data in frame.side_data:
        if data.type != av.sidedata.sidedata.Type.DISPLAYMATRIX:
            continue
        a, b, _, c, d = np.frombuffer(bytes(data), dtype=np.int32)[:5].tolist()
        if (a, b, c, d) == (1 << 16, 0, 0, 1 << 16):
            return None
        if a * d - b * c < 0:
            return "mirrored"
        return f"rotated {round(frame.rotation) % 360} degrees counter-clockwise"
    return None


def _open_container(path: Path) -> av.container.InputContainer:
    try:
        return av.open(str(path), mode="r")
    except av.error.FFmpegError as exc:
        if path.is_file() and path.stat().st_size == 0:
            raise VideoError(f"{path}: empty file (0 bytes)") from None
        raise VideoError(f"{path}: not a readable video ({exc.strerror or exc})") from None
    except OSError as exc:
        raise VideoError(f"{path}: cannot open ({exc})") from None


def open_video(
    path: str | Path, *, fps: float | None = None, on_conversion: ConversionPolicy = "warn"
) -> VideoSource:
    """Open a video file, PNG folder or .npy array for probing and streaming."""
    return VideoSource(path, fps=fps, on_conversion=on_conversion)


def probe_video(path: str | Path, *, fps: float | None = None) -> VideoInfo:
    """fps, frame count, size, pixel format and codec of a video, without decoding it."""
    return VideoSource(path, fps=fps).info


def read_video(
    path: str | Path,
    *,
    fps: float | None = None,
    max_frames: int | None = None,
    on_conversion: ConversionPolicy = "warn",
) -> np.ndarray:
    """Decode a whole video to a (T, H, W, 3) uint8 RGB array."""
    return VideoSource(path, fps=fps, on_conversion=on_conversion).read(max_frames)


def iter_clips(
    path: str | Path,
    clip_len: int,
    *,
    fps: float | None = None,
    on_conversion: ConversionPolicy = "warn",
) -> Iterator[np.ndarray]:
    """Stream a video as clips of ``clip_len`` frames (the last may be shorter)."""
    return VideoSource(path, fps=fps, on_conversion=on_conversion).clips(clip_len)


ROUNDED_TIMESTAMPS_S = 2e-3
"""How far timestamps rounded to milliseconds (captures remuxed by OBS, FLV) can move a video's
length: its start and its end by up to 1 ms each."""


def _frame_rate(stream: av.video.stream.VideoStream, frames: int) -> Fraction | None:
    """The stream's average frame rate, or its nominal one (FFmpeg's r_frame_rate) where the
    two differ only as much as timestamps rounded to milliseconds explain: 60 fps stored with
    1 ms timestamps averages 60.0019 over 10 s, and is 60 for the player and the metrics."""
    average, nominal = stream.average_rate, stream.base_rate
    if average and nominal and frames and average != nominal and abs(
            frames / float(average) - frames / float(nominal)) <= ROUNDED_TIMESTAMPS_S:
        return Fraction(nominal)
    return average or stream.guessed_rate or nominal


def _as_fraction(fps: float | Fraction) -> Fraction:
    if isinstance(fps, Fraction):
        return fps
    return Fraction(fps).limit_denominator(1001)


def write_video(
    path: str | Path,
    frames: np.ndarray | Iterable[np.ndarray],
    fps: float | Fraction,
    *,
    codec: LosslessCodec = "ffv1",
) -> Path:
    """Write uint8 RGB frames losslessly; returns the path.

    ``codec="ffv1"`` (default) stores RGB exactly in FFV1 (Matroska, ``.mkv``); ``"x264rgb"``
    uses x264's RGB mode at qp 0 (``.mkv``, widely playable); ``"utvideo"`` writes UT Video in
    AVI (``.avi``), the fastest to decode (see :mod:`stimuli_manifests.lossless`). The output
    is byte-identical for identical input, so generated stimuli are reproducible.
    """
    path = Path(path)
    try:
        spec = codec_spec(codec)
    except KeyError as exc:
        raise VideoError(str(exc.args[0])) from None
    if path.suffix.lower() != spec.suffix:
        raise VideoError(f"{path}: {codec} stimuli are written as {spec.container}; use a "
                         f"{spec.suffix} name")
    if not float(fps) > 0:
        raise VideoError(f"{path}: fps must be positive, got {fps}")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    rate = _as_fraction(fps)
    count = 0
    try:
        with av.open(str(tmp), mode="w", format=spec.container) as container:
            container.flags |= av.container.Flags.bitexact.value
            stream = container.add_stream(spec.encoder, rate=rate)
            stream.pix_fmt = spec.pix_fmt
            stream.options = dict(spec.options)
            stream.codec_context.flags |= av.codec.context.Flags.bitexact.value
            stream.thread_count = 1
            for frame in frames:
                arr = np.asarray(frame)
                if arr.dtype != np.uint8 or arr.ndim != 3 or arr.shape[2] != 3:
                    raise VideoError(
                        f"{path}: frame {count} has shape {arr.shape} and dtype {arr.dtype}; "
                        "expected (height, width, 3) uint8 RGB"
                    )
                if count == 0:
                    stream.width, stream.height = arr.shape[1], arr.shape[0]
                elif arr.shape[:2] != (stream.height, stream.width):
                    raise VideoError(f"{path}: frame {count} changes the frame size")
                vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(arr), format="rgb24")
                vf.pts = count
                for packet in stream.encode(vf):
                    container.mux(packet)
                count += 1
            if count == 0:
                raise VideoError(f"{path}: no frames to write")
            for packet in stream.encode():
                container.mux(packet)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
