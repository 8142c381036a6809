"""``cgvq-study init`` on renders that are damaged or odd in ways the frames alone do not
show: a truncated file, a checksum error inside a frame, uneven timestamps, lossy H.264,
two stimuli that would share one study file, and folders reached through symbolic links.

Each file is written here with known content, so every expectation follows from how it was
made (cut at 60 %, 300 bytes overwritten, a 300 ms gap), not from a captured run.
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
from support.cli import study_init as init
from support.encode import encode

from stimuli_manifests import load_manifest, write_video

SIZE = (48, 64)
FRAMES = 30


def clip(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (FRAMES, *SIZE, 3), dtype=np.uint8)


def scene(folder: Path) -> Path:
    """A scene with a good reference and a good test video."""
    write_video(folder / "s" / "reference.mkv", clip(1), 30)
    write_video(folder / "s" / "good_L1.mkv", clip(2), 30)
    return folder / "s"


def write_timed(path: Path, frames: np.ndarray, pts_ms: list[int], *, codec: str = "ffv1",
                pix_fmt: str = "bgr0", options: dict[str, str] | None = None) -> None:
    """Frames with the given presentation times in milliseconds."""
    encode(path, frames, codec=codec, pix_fmt=pix_fmt, options=options, pts=pts_ms,
           time_base=Fraction(1, 1000))


def problem_line(out: str, file: str) -> str:
    """The row of init's problem table that names ``file``."""
    problems = out.split("problems (", 1)[1]
    return next(row for row in problems.splitlines() if file in row)


def test_a_truncated_file_is_a_problem_not_a_shorter_video(tmp_path, capsys):
    renders = tmp_path / "renders"
    folder = scene(renders)
    data = (folder / "good_L1.mkv").read_bytes()
    (folder / "cut_L2.mkv").write_bytes(data[: len(data) * 6 // 10])
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2 and not (tmp_path / "study").exists()
    assert "s/cut_L2.mkv" in out and "damaged" in out


def test_a_header_promising_more_frames_than_decode_is_a_problem(tmp_path, capsys):
    """An MP4 with its index first, cut short: the container says 30 frames, fewer decode.
    The player and the metrics take the container's count, so init must not accept it."""
    renders = tmp_path / "renders"
    folder = scene(renders)
    whole = encode(tmp_path / "whole.mp4", clip(3), codec="libx264rgb", options={"qp": "0"},
                   container_options={"movflags": "+faststart"})
    data = whole.read_bytes()
    (folder / "cut_L2.mp4").write_bytes(data[: len(data) * 6 // 10])
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2
    line = problem_line(out, "cut_L2.mp4")
    assert "truncated or damaged: its container lists 30 frames but" in line


def test_a_checksum_error_inside_a_frame_is_a_problem(tmp_path, capsys):
    """FFV1 with slice checksums: overwriting bytes in the middle decodes without an
    exception but with wrong pixels; FFmpeg reports the checksum mismatch."""
    renders = tmp_path / "renders"
    folder = scene(renders)
    steady = [round(i * 1000 / 30) for i in range(FRAMES)]
    write_timed(tmp_path / "crc.mkv", clip(2), steady, options={"level": "3", "slicecrc": "1"})
    data = bytearray((tmp_path / "crc.mkv").read_bytes())
    middle = len(data) // 2
    data[middle:middle + 300] = np.random.default_rng(5).integers(0, 256, 300,
                                                                   dtype=np.uint8).tobytes()
    (folder / "garbled_L3.mkv").write_bytes(bytes(data))
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2
    line = problem_line(out, "garbled_L3.mkv")
    assert "damaged: the decoder reported ffv1" in line


def test_uneven_timestamps_are_named_and_a_skip_its_reference_lacks_is_refused(tmp_path,
                                                                              capsys):
    """A 300 ms gap in a 30 fps test: 9 frame slots skipped where its (steady) reference
    skips none, so from frame 15 on the pair is out of step: a mismatch, not only timing."""
    renders = tmp_path / "renders"
    folder = scene(renders)
    steady = [round(i * 1000 / 30) for i in range(FRAMES)]
    gap = [t if i < 15 else t + 300 for i, t in enumerate(steady)]
    write_timed(folder / "gap_L2.mkv", clip(4), gap)
    write_timed(folder / "steady_L3.mkv", clip(5), steady)  # 33 and 34 ms in turn: even
    code, out, err = init(capsys, renders, "--out", tmp_path / "study")
    warned = [line for line in (out + err).splitlines() if "uneven timestamps" in line]
    assert len(warned) == 1 and "gap_L2.mkv" in warned[0]
    assert "333 ms between frames 14 and 15, where most are 33 ms" in warned[0]
    assert code == 2
    refused = [line for line in out.splitlines() if line.lstrip().startswith("mismatch")]
    assert len(refused) == 1 and "gap_L2.mkv" in refused[0]
    assert "skip 9 frame slot(s)" in refused[0] and "skip 0:" in refused[0]
    # the same gap in the reference too: in step, so only the timing warning
    write_timed(folder / "reference.mkv", clip(1), gap)
    for even in ("steady_L3.mkv", "good_L1.mkv"):
        (folder / even).unlink()
    code, out, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 0 and "out of step" not in out + err


def test_lossy_h264_is_warned_about_and_lossless_h264_is_not(tmp_path, capsys):
    renders = tmp_path / "renders"
    folder = scene(renders)
    steady = [round(i * 1000 / 30) for i in range(FRAMES)]
    write_timed(folder / "lossy_L2.mkv", clip(6), steady, codec="libx264", pix_fmt="yuv420p",
                options={"crf": "18"})
    write_video(folder / "x264_L3.mkv", clip(7), 30, codec="x264rgb")
    code, out, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 0
    text = out + err
    warned = [line for line in text.splitlines() if "H.264 in profile" in line]
    assert len(warned) == 1 and "(s/lossy_L2.mkv)" in warned[0]
    assert "H.264 in profile High (yuv420p) is lossy" in warned[0]


def test_transcodes_that_would_share_a_file_are_refused(tmp_path, capsys):
    renders = tmp_path / "renders"
    folder = scene(renders)
    write_video(folder / "x264_L2.mkv", clip(8), 30, codec="x264rgb")
    (tmp_path / "map.csv").write_text(
        "path,scene,role,method,level\n"
        "s/reference.mkv,s,reference,,\n"
        "s/good_L1.mkv,s,test,ours,1\n"
        "s/x264_L2.mkv,s,test,base,1\n", encoding="utf-8")
    # ours_L1 and base_L1 come from different files: no problem when copied as they are
    code, _, _ = init(capsys, renders, "--mapping", tmp_path / "map.csv", "--out",
                      tmp_path / "copied")
    assert code == 0
    os.rename(folder / "x264_L2.mkv", folder / "good_L1.mp4")
    (tmp_path / "map.csv").write_text(
        "path,scene,role,method,level\n"
        "s/reference.mkv,s,reference,,\n"
        "s/good_L1.mkv,s,test,ours,1\n"
        "s/good_L1.mp4,s,test,base,1\n", encoding="utf-8")
    code, out, _ = init(capsys, renders, "--mapping", tmp_path / "map.csv", "--out",
                        tmp_path / "study", "--transcode", "utvideo")
    assert code == 2 and not (tmp_path / "study").exists()
    line = next(row for row in out.splitlines() if row.lstrip().startswith("shared file"))
    assert "s/good_L1.mkv" in line and "s/good_L1.mp4" in line
    assert "would be stored as videos/s/good_L1.avi, the same file as" in line
    assert line.endswith("once transcoded; rename one of them")


def test_names_that_differ_only_in_case_are_refused(tmp_path, capsys):
    """One file on the participants' macOS and Windows disks."""
    renders = tmp_path / "renders"
    folder = scene(renders)
    write_video(folder / "Good_L1.mkv", clip(9), 30)
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2
    assert "the same file as" in out and "Good_L1.mkv" in out


def test_a_linked_scene_folder_is_included_and_a_broken_link_is_a_problem(tmp_path, capsys):
    renders, elsewhere = tmp_path / "renders", tmp_path / "other_disk"
    scene(renders)
    write_video(elsewhere / "bistro" / "reference.mkv", clip(10), 30)
    write_video(elsewhere / "bistro" / "dlss_L1.mkv", clip(11), 30)
    (renders / "bistro").symlink_to(elsewhere / "bistro", target_is_directory=True)
    (renders / "s" / "loop").symlink_to(renders, target_is_directory=True)  # a cycle
    code, _, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 0
    ids = {str(c.id) for c in load_manifest(tmp_path / "study" / "manifest.json")
           .manifest.conditions}
    assert ids == {"s_good_L1", "bistro_dlss_L1"}
    (renders / "s" / "gone_L2.mkv").symlink_to(tmp_path / "nowhere.mkv")
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study2")
    assert code == 2
    assert "s/gone_L2.mkv" in out and "which does not exist" in out


def test_a_csv_row_naming_a_folder_says_so(tmp_path, capsys):
    renders = tmp_path / "renders"
    scene(renders)
    (renders / "s" / "frames").mkdir()
    (tmp_path / "map.csv").write_text(
        "path,scene,role,method,level\n"
        "s/reference.mkv,s,reference,,\n"
        "s/frames,s,test,ours,1\n", encoding="utf-8")
    code, out, _ = init(capsys, renders, "--mapping", tmp_path / "map.csv", "--out",
                        tmp_path / "study")
    assert code == 2
    assert "s/frames is a folder; init takes video files" in out


def test_display_advice_names_init_options(tmp_path, capsys):
    renders = tmp_path / "renders"
    write_video(renders / "s" / "reference.mkv", clip(1), 120)
    write_video(renders / "s" / "fast_L1.mkv", clip(2), 120)
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2
    assert "pass a higher --min-refresh-hz" in out and "in the manifest" not in out


def test_a_second_video_stream_is_named(tmp_path, capsys):
    renders = tmp_path / "renders"
    folder = scene(renders)
    path = folder / "two_L2.mkv"
    with av.open(str(path), "w") as container:
        streams = [container.add_stream("ffv1", rate=30) for _ in range(2)]
        for stream in streams:
            stream.width, stream.height, stream.pix_fmt = SIZE[1], SIZE[0], "bgr0"
        for i, frame in enumerate(clip(12)):
            for stream in streams:
                vf = av.VideoFrame.from_ndarray(frame, format="rgb24")
                vf.pts = i
                for packet in stream.encode(vf):
                    container.mux(packet)
        for stream in streams:
            for packet in stream.encode():
                container.mux(packet)
    code, out, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 0
    warned = [line for line in (out + err).splitlines() if "video streams" in line]
    assert len(warned) == 1 and "2 video streams; only the first" in warned[0]
    assert "two_L2.mkv" in warned[0]
