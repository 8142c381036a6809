"""Video probing, decoding and lossless writing, checked against the frames we generate."""

from __future__ import annotations

import logging
from fractions import Fraction

import av
import numpy as np
import pytest
from PIL import Image
from support.encode import encode

from stimuli_manifests import (
    VideoError,
    iter_clips,
    open_video,
    probe_video,
    read_video,
    sha256_file,
    write_video,
)


@pytest.fixture(scope="module")
def frames() -> np.ndarray:
    # Random content (worst case for lossless coding) of a size not divisible by 16.
    rng = np.random.default_rng(7)
    return rng.integers(0, 256, size=(11, 37, 50, 3), dtype=np.uint8)


@pytest.mark.parametrize("codec", ["ffv1", "x264rgb"])
def test_lossless_round_trip_is_exact(tmp_path, frames, codec):
    path = write_video(tmp_path / f"v_{codec}.mkv", frames, 30, codec=codec)
    decoded = read_video(path)
    assert decoded.dtype == np.uint8
    assert decoded.shape == frames.shape
    assert np.array_equal(decoded, frames)


@pytest.mark.parametrize("codec", ["ffv1", "x264rgb"])
def test_writing_is_byte_deterministic(tmp_path, frames, codec):
    a = write_video(tmp_path / "a.mkv", frames, 30, codec=codec)
    b = write_video(tmp_path / "b.mkv", iter(frames), 30, codec=codec)  # a generator too
    assert sha256_file(a) == sha256_file(b)


@pytest.mark.parametrize(
    ("fps", "expected"), [(30, 30.0), (60, 60.0), (Fraction(30000, 1001), 30000 / 1001), (24, 24.0)]
)
def test_probe(tmp_path, frames, fps, expected):
    path = write_video(tmp_path / "v.mkv", frames[:5], fps)
    info = probe_video(path)
    assert (info.width, info.height, info.frame_count) == (50, 37, 5)
    assert info.fps == pytest.approx(expected, rel=1e-9)
    assert info.duration == pytest.approx(5 / expected)
    assert info.codec == "ffv1" and info.bit_depth == 8 and not info.has_alpha
    assert info.kind == "video"


def test_clips_stream_the_video_in_order(tmp_path, frames):
    path = write_video(tmp_path / "v.mkv", frames, 30)
    clips = list(iter_clips(path, 4))
    assert [len(c) for c in clips] == [4, 4, 3]
    assert np.array_equal(np.concatenate(clips), frames)
    with pytest.raises(VideoError, match="at least 1"):
        list(iter_clips(path, 0))


def test_max_frames(tmp_path, frames):
    path = write_video(tmp_path / "v.mkv", frames, 30)
    assert np.array_equal(read_video(path, max_frames=3), frames[:3])


def test_png_folder(tmp_path, frames):
    folder = tmp_path / "pngs"
    folder.mkdir()
    for i, f in enumerate(frames[:4]):
        Image.fromarray(f).save(folder / f"frame_{i:04d}.png")
    (folder / "notes.txt").write_text("ignored")
    src = open_video(folder, fps=24)
    assert (src.info.kind, src.info.frame_count, src.info.fps) == ("frames", 4, 24.0)
    assert np.array_equal(src.read(), frames[:4])
    assert open_video(folder).info.fps == 30.0  # default for folders


def test_png_folder_errors(tmp_path, frames):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(VideoError, match=r"no \.png frames"):
        probe_video(empty)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    Image.fromarray(frames[0]).save(mixed / "0.png")
    Image.fromarray(frames[0][:10]).save(mixed / "1.png")
    with pytest.raises(VideoError, match="differs from the first frame"):
        read_video(mixed)


def test_npy_input(tmp_path, frames):
    path = tmp_path / "v.npy"
    np.save(path, frames)
    src = open_video(path, fps=60)
    assert (src.info.kind, src.info.frame_count, src.info.width, src.info.height) == (
        "npy",
        11,
        50,
        37,
    )
    assert np.array_equal(src.read(), frames)


@pytest.mark.parametrize(
    ("array", "needle"),
    [
        (np.zeros((3, 8, 8, 3), dtype=np.float32), "dtype float32"),
        (np.zeros((8, 8, 3), dtype=np.uint8), r"is not \(frames, height, width, 3\)"),
        (np.zeros((0, 8, 8, 3), dtype=np.uint8), "no frames"),
    ],
)
def test_npy_errors(tmp_path, array, needle):
    path = tmp_path / "bad.npy"
    np.save(path, array)
    with pytest.raises(VideoError, match=needle):
        probe_video(path)


def test_corrupt_empty_missing_and_non_video_files(tmp_path, frames):
    garbage = tmp_path / "garbage.mkv"
    garbage.write_bytes(np.random.default_rng(1).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    for path, why in ((garbage, "not a readable video (Invalid data"),
                      (empty, "empty file (0 bytes)")):
        with pytest.raises(VideoError) as err:
            probe_video(path)
        # the path once, FFmpeg's reason without its errno number
        assert str(err.value).count(str(path)) == 1 and why in str(err.value)
        assert "Errno" not in str(err.value)
    with pytest.raises(VideoError, match="no such file"):
        probe_video(tmp_path / "missing.mkv")
    audio = tmp_path / "audio.mka"
    with av.open(str(audio), "w", format="matroska") as c:
        s = c.add_stream("pcm_s16le", rate=8000)
        frame = av.AudioFrame.from_ndarray(
            np.zeros((1, 800), np.int16), format="s16", layout="mono"
        )
        frame.sample_rate = 8000
        for p in s.encode(frame):
            c.mux(p)
        for p in s.encode():
            c.mux(p)
    with pytest.raises(VideoError, match="no video stream"):
        probe_video(audio)


def test_corrupted_payload_raises_with_path(tmp_path):
    # A valid container whose frame payloads are overwritten: decoding must fail cleanly.
    rng = np.random.default_rng(3)
    path = write_video(tmp_path / "v.mkv", rng.integers(0, 256, (6, 64, 64, 3), np.uint8), 30)
    data = bytearray(path.read_bytes())
    mid = len(data) // 3
    data[mid : mid + 2000] = rng.integers(0, 256, 2000, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))
    try:
        out = read_video(path)
    except VideoError as err:
        assert str(path) in str(err)
    else:  # FFmpeg may conceal damage; then the size must still be intact
        assert out.shape[1:] == (64, 64, 3)


def _write_10bit(path, n=3, size=16):
    frames = np.stack([np.full((size, size, 3), 40 * i, np.uint8) for i in range(n)])
    return encode(path, frames, pix_fmt="yuv420p10le")


def test_high_bit_depth_is_converted_with_warning_or_refused(tmp_path, caplog):
    path = _write_10bit(tmp_path / "ten.mkv")
    info = probe_video(path)
    assert info.bit_depth == 10 and info.needs_conversion
    with caplog.at_level(logging.WARNING):
        out = read_video(path)
    assert "10-bit" in caplog.text
    assert out.shape == (3, 16, 16, 3) and out.dtype == np.uint8
    assert abs(int(out[2].mean()) - 80) <= 3  # the grey level survives the conversion
    with pytest.raises(VideoError, match="10-bit"):
        open_video(path, on_conversion="error")


def test_alpha_png_folder_is_flagged(tmp_path):
    folder = tmp_path / "rgba"
    folder.mkdir()
    rgba = np.zeros((8, 8, 4), np.uint8)
    rgba[..., 0] = 200
    rgba[..., 3] = 128
    Image.fromarray(rgba, "RGBA").save(folder / "0.png")
    with pytest.raises(VideoError, match="alpha"):
        open_video(folder, on_conversion="error")
    out = read_video(folder)
    assert out.shape == (1, 8, 8, 3) and int(out[0, 0, 0, 0]) == 200


def test_write_rejects_bad_input(tmp_path):
    with pytest.raises(VideoError, match=r"\.mkv"):
        write_video(tmp_path / "v.mp4", np.zeros((1, 8, 8, 3), np.uint8), 30)
    with pytest.raises(VideoError, match="uint8"):
        write_video(tmp_path / "v.mkv", np.zeros((1, 8, 8, 3), np.float32), 30)
    with pytest.raises(VideoError, match="no frames"):
        write_video(tmp_path / "v.mkv", [], 30)
    with pytest.raises(VideoError, match="changes the frame size"):
        write_video(
            tmp_path / "v.mkv", [np.zeros((8, 8, 3), np.uint8), np.zeros((4, 8, 3), np.uint8)], 30
        )
    assert not list(tmp_path.glob("*.part"))  # no half-written files left behind
