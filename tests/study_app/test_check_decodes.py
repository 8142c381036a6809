"""``cgvq-study check`` on a hand-written manifest decodes every video, as ``init`` does: a
file cut short, whose container still promises its full length, is named as damaged (it
used to pass as a pair mismatch naming the container's count), and uneven timestamps are
warned about. Every file is made here, so the expectations follow from how it was made."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
from support.encode import encode

from cgvq_cli.study_cli import main
from session_store.study_folder import load_study
from stimuli_manifests import (
    fill_checksums,
    load_manifest,
    parse_manifest,
    save_manifest,
    write_video,
)
from study_app.study_check import check_study

FRAMES = 30


def _clip(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (FRAMES, 48, 64, 3), dtype=np.uint8)


def _hand_study(folder: Path, test_name: str) -> Path:
    """A manifest written by hand (no init) over videos/ref.mkv and videos/<test_name>."""
    manifest = parse_manifest({
        "study_id": "hand", "root": "videos", "protocol": {"repetitions": 1},
        "display": {"min_width": 640, "min_height": 480},
        "references": [{"path": "ref.mkv", "scene": "s"}],
        "conditions": [{"reference": "SRC01", "method": "m", "level": 1, "path": test_name},
                       {"reference": "SRC01", "method": "m", "level": 2, "path": "ok.mkv"}],
    })
    save_manifest(manifest, folder / "manifest.json")
    save_manifest(fill_checksums(load_manifest(folder / "manifest.json")),
                  folder / "manifest.json")
    return folder


def _videos(folder: Path) -> Path:
    videos = folder / "videos"
    videos.mkdir(parents=True)
    write_video(videos / "ref.mkv", _clip(1), 30)
    write_video(videos / "ok.mkv", _clip(2), 30)
    return videos


def test_a_file_cut_short_is_damaged_not_a_shorter_loop(tmp_path, capsys):
    videos = _videos(tmp_path / "study")
    whole = encode(tmp_path / "whole.mp4", _clip(3), codec="libx264rgb", options={"qp": "0"},
                   container_options={"movflags": "+faststart"})
    data = whole.read_bytes()
    (videos / "cut.mp4").write_bytes(data[: len(data) * 6 // 10])
    folder = _hand_study(tmp_path / "study", "cut.mp4")
    result = check_study(load_study(folder))
    assert not result.ok
    (line,) = [e for e in result.errors if "cut.mp4" in e]
    assert line.startswith("SRC01_HRC01: cut.mp4 truncated or damaged: its container lists "
                           f"{FRAMES} frames but ")
    assert not any("both loops must match" in e for e in result.errors)
    assert main(["check", str(folder)]) == 2
    assert "truncated or damaged" in capsys.readouterr().err


def test_uneven_timestamps_are_warned_about_by_check(tmp_path):
    videos = _videos(tmp_path / "study")
    steady = [round(i * 1000 / 30) for i in range(FRAMES)]
    gap = [t if i < 15 else t + 300 for i, t in enumerate(steady)]
    encode(videos / "gap.mkv", _clip(4), codec="ffv1", pix_fmt="bgr0", pts=gap,
           time_base=Fraction(1, 1000))
    result = check_study(load_study(_hand_study(tmp_path / "study", "gap.mkv")))
    assert result.ok, result.errors
    (warned,) = [w for w in result.warnings if "uneven timestamps" in w]
    assert warned.startswith("SRC01_HRC01: ") and "between frames 14 and 15" in warned
