"""Levels numbered the wrong way round are named by init, from the pixels it keeps while
decoding: renders whose distortion strength the test sets (Gaussian noise of known sigma)."""

from __future__ import annotations

import numpy as np
import pytest
from support.cli import study_init as init

from cgvq_cli.study_cli import main as study_main
from stimuli_manifests import write_video
from stimuli_manifests.from_folder.level_order import LevelSample, level_order_warnings
from stimuli_manifests.from_folder.pixel_sample import (
    SampleCollector,
    mean_squared_difference,
    sampled_frames,
    stride_for,
)

FPS = 30


def _reference(seed: int, frames: int = 12, size=(96, 128)) -> np.ndarray:
    """Mid-grey content (60..190), so that added noise is never clipped."""
    rng = np.random.default_rng(seed)
    return rng.integers(60, 191, (frames, *size, 3)).astype(np.uint8)


def _noisy(ref: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    noise = np.random.default_rng(seed).normal(0, sigma, ref.shape)
    return np.clip(np.rint(ref + noise), 0, 255).astype(np.uint8)


def _sample(frames: np.ndarray):
    c = SampleCollector(len(frames))
    for i, f in enumerate(frames):
        c.add(i, f)
    return c.sample()


def test_the_sample_spans_the_video_and_estimates_the_full_difference():
    assert sampled_frames(12) == (0, 2, 4, 7, 9, 11)
    assert sampled_frames(3) == (0, 1, 2) and sampled_frames(0) == ()
    assert stride_for(1080, 1920) == 8 and stride_for(2160, 3840) == 16
    assert stride_for(48, 64) == 1
    ref = _reference(1, frames=12, size=(720, 1280))
    test = _noisy(ref, 12.0, 2)
    full = float(np.mean((test.astype(float) - ref.astype(float)) ** 2))
    assert full == pytest.approx(144.0, rel=0.02)  # sigma squared: nothing was clipped
    estimate = mean_squared_difference(_sample(test), _sample(ref))
    assert estimate == pytest.approx(full, rel=0.05)
    assert _sample(test).pixels.shape == (6, 120, 214, 3)  # every 6th pixel: 6 = ceil(5.3)
    shorter = _sample(test[:10])
    assert mean_squared_difference(shorter, _sample(ref)) is None  # other frames sampled


def _renders(folder, levels: dict[str, dict[int, float]]) -> None:
    seed = 10
    for scene in ("forest", "city"):
        ref = _reference(seed)
        write_video(folder / scene / "reference.mkv", ref, FPS)
        for method, sigmas in levels.items():
            for level, sigma in sigmas.items():
                seed += 1
                write_video(folder / scene / f"{method}_L{level}.mkv",
                            _noisy(ref, sigma, seed), FPS)
        seed += 100


def test_init_names_a_method_whose_level_1_is_the_mildest(tmp_path, capsys):
    renders = tmp_path / "renders"
    _renders(renders, {"denoise": {1: 30.0, 2: 15.0, 3: 5.0},  # level 1 strongest: right
                       "spp": {1: 5.0, 2: 15.0, 3: 30.0}})  # numbered by sample count
    code, out, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 0, out + err
    lines = [ln for ln in out.splitlines() if "numbered the wrong way round" in ln]
    # the method first, as check prints it (it used to trail the 60-word sentence)
    assert len(lines) == 1 and lines[0].startswith("  warning: method 'spp': the levels"), lines
    assert "level 1 is closer to its reference in pixels than level 3 in 2 of 2 scene(s)" \
        in lines[0]
    msd = [float(x) for x in lines[0].split("mean squared difference ")[1]
           .split(" in scene")[0].split(" against ")]
    assert msd == pytest.approx([25.0, 900.0], rel=0.1)  # sigma 5 and 30, squared
    assert "renumber its files (level 1 becomes level 3, level 3 level 1, and so on) or map " \
        "them in a CSV" in lines[0]
    assert "e+0" not in lines[0]  # 900, not 9e+02
    # check says it again of the study folder (a study edited or built by hand)
    assert study_main(["check", str(tmp_path / "study")]) == 0
    out = capsys.readouterr().out
    assert out.count("numbered the wrong way round") == 1 and "method 'spp'" in out


def test_a_method_reversed_in_one_scene_of_three_is_not_named():
    def sample(value: int):
        return _sample(np.full((3, 8, 8, 3), value, np.uint8))

    refs = {s: sample(100) for s in ("a", "b", "c")}
    tests = [LevelSample("m", "a", 1, sample(110)), LevelSample("m", "a", 2, sample(120)),
             LevelSample("m", "b", 1, sample(130)), LevelSample("m", "b", 2, sample(110)),
             LevelSample("m", "c", 1, sample(130)), LevelSample("m", "c", 2, sample(105)),
             LevelSample("one", "a", 1, sample(101))]  # one level: nothing to compare
    assert level_order_warnings(tests, refs) == []
    tests[2] = LevelSample("m", "b", 1, sample(101))  # now reversed in 2 of 3
    (warning,) = level_order_warnings(tests, refs)
    assert warning.startswith("method 'm': the levels look numbered the wrong way round: "
                              "level 1 is closer to its reference in pixels than level 2 in "
                              "2 of 3 scene(s) (mean squared difference 100 against 400 in "
                              "scene 'a')")
