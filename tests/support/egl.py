"""Off-screen OpenGL (EGL): whether a context can be made here, and a fixture that skips."""

from __future__ import annotations

import pytest


def egl_unavailable() -> str | None:
    """None when an EGL OpenGL 3.3 context can be created, else why not."""
    try:
        import moderngl

        ctx = moderngl.create_standalone_context(backend="egl", require=330)
        ctx.release()
        return None
    except Exception as exc:  # any failure means: no off-screen GL here
        return f"no EGL OpenGL 3.3 context can be created here ({exc}); install Mesa EGL"


@pytest.fixture(scope="session")
def egl() -> None:
    reason = egl_unavailable()
    if reason:
        pytest.skip(reason)
