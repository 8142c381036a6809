"""A study file missing on the participant's computer is the display check's finding, shown
on its screen, even when it is a video of the first trial (which the check decodes to time
it: that used to close the window with a decoding error meant for the experimenter)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from .test_screens_gui import PILOT, _make_study

pytestmark = pytest.mark.gui

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "study_app" / "missing-files"


def test_a_missing_video_of_the_first_trial_gets_the_check_screen(tmp_path, xdisplay,
                                                                  app_driver):
    study = _make_study(tmp_path / "study", (480, 360), (800, 600))
    (study / "videos" / "ref0.mkv").unlink()  # the reference of every trial, the first too
    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    app = app_driver(xdisplay, [str(study), "--participant", "P01", "--windowed",
                                "--screenshots", str(ARTIFACTS), PILOT])
    assert app.leave_failed_preflight("Escape") == 2
    errors = [ln for ln in app.lines if "error" in ln.lower()]
    assert errors and "checksums: stimulus files are missing or modified" in errors[-1], errors
    assert "ref0.mkv" in errors[-1]
    assert "cannot decode" not in " ".join(app.lines)
    assert "cgvq-study check" not in " ".join(app.lines)  # an experimenter's command
    assert (ARTIFACTS / "preflight-failed.png").exists()
