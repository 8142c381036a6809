"""Fixtures of the synthetic-stimuli tests: one tiny synthesized study (``egl``, the EGL
context or a skip, comes from tests/support)."""

from __future__ import annotations

from pathlib import Path

import pytest

TINY = {"width": 64, "height": 64, "seconds": 0.2, "fps": 30, "seed": 7}


@pytest.fixture(scope="session")
def tiny_options() -> dict:
    return dict(TINY)


@pytest.fixture(scope="session")
def tiny_study(egl, tmp_path_factory) -> Path:
    """A 64x64, 0.2 s study with both scenes and all six families (manifest path)."""
    from study_app.synth import SynthOptions, synthesize

    out = tmp_path_factory.mktemp("synth") / "study"
    return synthesize(out, SynthOptions(**TINY), progress=False)
