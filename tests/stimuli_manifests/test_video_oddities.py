"""Renders as researchers have them: display matrices, non-square pixels, frame folders
numbered without zero-padding. Each either reads exactly as a media player shows it or is
refused in one line; none may give frames other than the ones written, silently.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest
from PIL import Image
from support.encode import encode

from stimuli_manifests import VideoError, probe_video, read_video
from stimuli_manifests.pairs import same_frame_rate

FRAMES = np.random.default_rng(7).integers(0, 256, (4, 32, 48, 3), dtype=np.uint8)


def write_h264(path: Path, *, rotation: int | None = None, hflip: bool = False,
               sar: Fraction | None = None) -> Path:
    """Lossless x264 (RGB mode) with an optional display matrix or pixel aspect ratio."""
    def setup(stream: av.video.stream.VideoStream) -> None:
        if rotation is not None:
            stream.set_display_rotation(rotation, hflip=hflip)
        if sar is not None:
            stream.sample_aspect_ratio = sar

    return encode(path, FRAMES, codec="libx264rgb", options={"qp": "0"}, setup=setup)


@pytest.mark.parametrize(("rotation", "hflip", "what"), [
    (180, False, "rotated 180 degrees counter-clockwise"),
    (90, False, "rotated 90 degrees counter-clockwise"),
    (0, True, "mirrored"),
])
def test_a_display_matrix_is_refused(tmp_path, rotation, hflip, what):
    path = write_h264(tmp_path / "turned.mp4", rotation=rotation, hflip=hflip)
    # the file really carries the matrix a media player applies
    with av.open(str(path)) as c:
        frame = next(c.decode(video=0))
        assert any(sd.type.name == "DISPLAYMATRIX" for sd in frame.side_data)
    with pytest.raises(VideoError, match=f"display matrix \\({what}\\)"):
        probe_video(path)


def test_an_identity_display_matrix_and_none_read_exactly(tmp_path):
    for path in (write_h264(tmp_path / "identity.mp4", rotation=0),
                 write_h264(tmp_path / "plain.mkv")):
        assert np.array_equal(read_video(path), FRAMES)


def test_non_square_pixels_are_refused(tmp_path):
    path = write_h264(tmp_path / "anamorphic.mkv", sar=Fraction(2, 1))
    with av.open(str(path)) as c:
        assert c.streams.video[0].sample_aspect_ratio == 2
    with pytest.raises(VideoError, match=r"non-square pixels \(sample aspect ratio 2:1\)"):
        probe_video(path)


def write_pngs(folder: Path, names: list[str], frames: np.ndarray) -> None:
    folder.mkdir()
    for name, frame in zip(names, frames, strict=True):
        Image.fromarray(frame).save(folder / name)


def test_unpadded_frame_numbers_read_in_frame_order(tmp_path):
    frames = np.random.default_rng(3).integers(0, 256, (12, 8, 8, 3), dtype=np.uint8)
    write_pngs(tmp_path / "seq", [f"frame_{i}.png" for i in range(12)], frames)
    # alphabetically frame_10 and frame_11 would come right after frame_1
    assert np.array_equal(read_video(tmp_path / "seq"), frames)


def test_a_number_elsewhere_in_the_name_does_not_decide(tmp_path):
    frames = np.random.default_rng(4).integers(0, 256, (11, 8, 8, 3), dtype=np.uint8)
    write_pngs(tmp_path / "seq", [f"shot2_v3.{i + 100}.png" for i in range(11)], frames)
    assert np.array_equal(read_video(tmp_path / "seq"), frames)


@pytest.mark.parametrize(("names", "needle"), [
    (["f_0.png", "f_1.png", "f_3.png"], r"1 missing number\(s\) \(2\)"),
    (["f_1.png", "f_01.png", "f_2.png"], "both carry frame number 1"),
    (["f_0.png", "last.png"], "last.png has no frame number"),
])
def test_frame_folders_that_do_not_give_one_order_are_refused(tmp_path, names, needle):
    frames = np.zeros((len(names), 4, 4, 3), dtype=np.uint8)
    write_pngs(tmp_path / "seq", names, frames)
    with pytest.raises(VideoError, match=needle):
        probe_video(tmp_path / "seq")


def test_ntsc_rate_is_not_thirty():
    assert not same_frame_rate(30000 / 1001, 30.0)
    assert same_frame_rate(30000 / 1001, 29.97003)
    assert same_frame_rate(30.0, 30.0)
