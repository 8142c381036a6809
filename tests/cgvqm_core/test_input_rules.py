"""Rules the metrics share with the study tools: one frame-rate rule, and a failed batch
leaves no scores file behind."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import numpy as np
from support.encode import encode

from cgvq_cli.study_cli import main as study_main
from cgvqm_core.cli import main
from stimuli_manifests import write_video

SIZE = (32, 48)


def clip(seed: int, frames: int = 10) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (frames, *SIZE, 3), dtype=np.uint8)


def run(capsys, *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_ntsc_against_thirty_fps_needs_allow_resample(tmp_path, capsys):
    """29.97 is not 30: init refuses such a pair, and so must the metrics (a relative
    tolerance of 1e-3 let it through, exactly at the edge)."""
    ref = write_video(tmp_path / "ref.mkv", clip(1), 30)
    test = write_video(tmp_path / "test.mkv", clip(2), Fraction(30000, 1001))
    with av.open(str(test)) as c:
        assert c.streams.video[0].average_rate == Fraction(30000, 1001)
    code, _, err = run(capsys, "score", "--metric", "psnr", "--ref", ref, "--test", test)
    assert code == 2 and "--allow-resample" in err and "Traceback" not in err
    code, out, _ = run(capsys, "score", "--metric", "psnr", "--ref", ref, "--test", test,
                       "--allow-resample")
    assert code == 0 and "psnr =" in out


def write_10bit(path: Path, frames: np.ndarray) -> Path:
    return encode(path, frames, pix_fmt="yuv444p10le")


def test_a_batch_refused_before_scoring_writes_no_csv(tmp_path, capsys):
    renders = tmp_path / "renders"
    write_10bit(renders / "s" / "reference.mkv", clip(3))
    write_10bit(renders / "s" / "deep_L1.mkv", clip(4))
    assert study_main(["init", str(renders), "--out", str(tmp_path / "study")]) == 0
    out, err = capsys.readouterr()
    assert "cgvqm scores it only with --allow-convert" in out + err
    scores = tmp_path / "scores.csv"
    code, _, err = run(capsys, "batch", "--manifest", tmp_path / "study" / "manifest.json",
                       "--out", scores, "--metrics", "psnr")
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == 2 and len(lines) == 1 and "--allow-convert" in lines[0]
    assert not scores.exists()  # not a header-only file the next step reads as no scores
    code, _, _ = run(capsys, "batch", "--manifest", tmp_path / "study" / "manifest.json",
                     "--out", scores, "--metrics", "psnr", "--allow-convert")
    assert code == 0 and len(scores.read_text().splitlines()) == 2
