"""Fixtures of the synthetic-stimuli tests: an EGL context (or a skip) and one tiny study."""

from __future__ import annotations

from pathlib import Path

import pytest

TINY = {"width": 64, "height": 64, "seconds": 0.2, "fps": 30, "seed": 7}


def _egl_available() -> str | None:
    try:
        import moderngl

        ctx = moderngl.create_standalone_context(backend="egl", require=330)
        ctx.release()
        return None
    except Exception as exc:  # any failure means: no off-screen GL here
        return f"no EGL OpenGL 3.3 context can be created here ({exc}); install Mesa EGL"


@pytest.fixture(scope="session")
def egl() -> None:
    reason = _egl_available()
    if reason:
        pytest.skip(reason)


@pytest.fixture(scope="session")
def tiny_options() -> dict:
    return dict(TINY)


@pytest.fixture(scope="session")
def tiny_study(egl, tmp_path_factory) -> Path:
    """A 64x64, 0.2 s study with both scenes and all six families (manifest path)."""
    from study_app.synth import SynthOptions, synthesize

    out = tmp_path_factory.mktemp("synth") / "study"
    return synthesize(out, SynthOptions(**TINY), progress=False)
