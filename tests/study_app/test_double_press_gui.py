"""A double press on Submit (Enter twice, 150 ms apart) records the rating and must leave the
next screen standing: the second press used to choose that screen's action as it appeared, so
the participant never saw the end of the practice or the end screen (which says what to send).
Real X input on a virtual display, as in :mod:`test_gui_e2e`."""

from __future__ import annotations

import subprocess

import pytest

from session_store import read_ratings

pytestmark = pytest.mark.gui

PILOT = "--pilot-no-vsync"


def _double_enter(app) -> None:
    """Move the slider (an untouched one cannot be submitted), then Enter twice."""
    app.key("Right")
    subprocess.run(["xdotool", "key", "--delay", "150", "Return", "Return"], env=app.env,
                   check=True)


def _stays(app, screen: str) -> None:
    """``screen`` opened and was not closed by the press meant for the screen before."""
    app.wait(screen)
    assert app.wait(f"{screen}-done", timeout=1.0, required=False) is None


@pytest.mark.slow  # about 14 s: CI runs it after `make test` (.ci/run), as does `make test-slow`
def test_double_enter_on_submit_leaves_the_next_screen_standing(tmp_path, xdisplay,
                                                                 study_factory, app_driver):
    study = study_factory(tmp_path / "study")
    session = study / "sessions" / "P01.sqlite"
    app = app_driver(xdisplay, [str(study), "--participant", "P01", "--seed", "5",
                                "--max-dropped-frames", "-1", "--practice", "1", PILOT])
    app.through_consent()
    app.wait("practice")
    app.key("space")
    app.wait("viewing trial=-1 practice=1")
    app.open_rating()
    _double_enter(app)
    _stays(app, "practice-end")
    app.key("space")

    n = 3
    for trial in range(n):
        app.wait(f"viewing trial={trial}")
        app.open_rating()
        _double_enter(app)
        app.wait(f"recorded trial={trial}")
    _stays(app, "end")
    app.key("Return")
    code, out = app.finish()
    assert code == 0, out
    rows, problems = read_ratings(session)
    assert problems == [] and [r["trial"] for r in rows] == list(range(n))
