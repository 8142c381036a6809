"""Tiny study folders made on the fly (real videos, real manifest): the input of every test
that runs the participant's app or a ``cgvq-study`` command on a study."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stimuli_manifests import (
    fill_checksums,
    load_manifest,
    parse_manifest,
    save_manifest,
    write_video,
)


def reference_frames(size: int, frames: int, seed: int) -> np.ndarray:
    """A moving pattern whose every frame differs (so frame indices are visible)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    base = rng.integers(0, 256, size=3)
    out = np.empty((frames, size, size, 3), dtype=np.uint8)
    for t in range(frames):
        for c in range(3):
            out[t, :, :, c] = (base[c] + 4 * xx + 2 * yy + 7 * t * (c + 1)) % 256
    return out


def make_study(folder: Path, *, size: int = 64, fps: float = 30, seconds: float = 1.0,
               refs: int = 1, repetitions: int = 1, min_display=(640, 480),
               briefing: bool = True, consent: bool = True) -> Path:
    """A study folder: ``refs`` references, each with two noisy conditions (levels 1, 2)."""
    folder.mkdir(parents=True, exist_ok=True)
    n = round(fps * seconds)
    references, conditions = [], []
    for r in range(refs):
        ref = reference_frames(size, n, seed=r)
        write_video(folder / "videos" / f"ref{r}.mkv", ref, fps)
        references.append({"path": f"ref{r}.mkv", "scene": f"scene{r}", "width": size,
                           "height": size, "fps": fps, "frames": n})
        rng = np.random.default_rng(100 + r)
        for level, sigma in ((1, 40), (2, 10)):
            noisy = np.clip(ref + rng.normal(0, sigma, ref.shape), 0, 255).astype(np.uint8)
            write_video(folder / "videos" / f"ref{r}_noise{level}.mkv", noisy, fps)
            conditions.append({"reference": f"SRC{r + 1:02d}", "method": "noise",
                               "level": level, "path": f"ref{r}_noise{level}.mkv"})
    manifest = parse_manifest({
        "study_id": "tiny-study", "root": "videos",
        "protocol": {"repetitions": repetitions, "blank_seconds": 0.5},
        "display": {"min_width": min_display[0], "min_height": min_display[1],
                    "min_refresh_hz": 59},
        "references": references, "conditions": conditions,
    })
    if briefing:
        (folder / "briefing.md").write_text(
            "# Welcome\n\nYou will see short videos and rate their quality.\n", encoding="utf-8")
    if consent:
        (folder / "consent.md").write_text("I agree that my ratings are stored.\n",
                                           encoding="utf-8")
    save_manifest(manifest, folder / "manifest.json")
    save_manifest(fill_checksums(load_manifest(folder / "manifest.json")),
                  folder / "manifest.json")
    return folder


@pytest.fixture
def study_factory():
    """``make_study`` for tests that need their own variant of the tiny study."""
    return make_study


@pytest.fixture
def tiny_study(tmp_path: Path) -> Path:
    return make_study(tmp_path / "study")
