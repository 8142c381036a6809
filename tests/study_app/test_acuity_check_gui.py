"""The contrast/acuity check in the real app under Xvfb: the card calibrated with keys and the
mouse wheel, optotypes answered by an observer with known thresholds, the optotype's size on
screen measured from a screenshot, the result stored; a failed check with ``on_fail: end``
closes the session politely."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from support.studies import make_study

from session_store import read_session
from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest
from study_app.vision.acuity import ORIENTATIONS, card_calibration, grey_levels
from study_app.vision.acuity_plan import acuity_plan
from study_app.vision.acuity_scoring import OptotypeAnswer, next_trial

pytestmark = pytest.mark.gui
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "study_app" / "acuity"
KEYS = {"left": "Left", "up": "Up", "right": "Right", "down": "Down"}


def _study(tmp_path: Path, on_fail: str) -> Path:
    study = make_study(tmp_path / "study", min_display=(640, 480))
    path = study / "manifest.json"
    data = json.loads(path.read_text())
    data["panel"] = {"vision_screening": {"colour": False, "acuity": True,
                                          "viewing_distance_cm": 60, "on_fail": on_fail}}
    save_manifest(parse_manifest(data), path)
    save_manifest(fill_checksums(load_manifest(path)), path)
    return study


def _start(app) -> None:
    app.through_consent()
    app.wait("acuity-check")
    app.key("space")
    app.wait("acuity-card")


def _answer_all(app, plan, *, logmar: float, weber: float) -> int:
    """Answer every optotype like an observer who reads those at least ``logmar`` large and
    ``weber`` strong and misreads the rest, checking that the app shows the trials the rule
    asks for, in order; the number shown."""
    answers: list[OptotypeAnswer] = []
    while (trial := next_trial(plan, answers)) is not None:
        line = app.wait("acuity-trial")
        assert f"index={len(answers) + 1} series={trial.series} level={trial.level}" in line
        sees = trial.logmar >= logmar - 1e-9 and trial.contrast >= weber - 1e-9
        way = trial.orientation if sees else next(o for o in ORIENTATIONS
                                                  if o != trial.orientation)
        app.key(KEYS[way])
        answers.append(OptotypeAnswer(trial, way, 0.0))
    return len(answers)


@pytest.mark.slow  # about 19 s: CI runs it after `make test` (.ci/run), as does `make test-slow`
def test_the_check_measures_the_screen_and_records_the_thresholds(tmp_path, xdisplay,
                                                                  app_driver):
    study = _study(tmp_path, "flag")
    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    app = app_driver(xdisplay, [str(study), "--participant", "P01", "--seed", "3",
                                "--practice", "0", "--pilot-no-vsync",
                                "--screenshots", str(ARTIFACTS)])
    _start(app)
    app.key(*["shift+Right"] * 10)  # 324 px (a 96 dpi start) + 100
    subprocess.run(["xdotool", "click", "--repeat", "2", "4"], env=xdisplay, check=True)
    app.key("Left")
    app.key("Return")
    app.wait("acuity-card-done width=425")
    geometry = card_calibration(425, 60)
    plan = acuity_plan(geometry, 3)
    app.wait("acuity-trials")
    app.key("space")
    shown = _answer_all(app, plan, logmar=0.2, weber=0.063)
    # 1.0..0.2 read in three each, 0.1 missed three times (0.0 is under a pixel here);
    # contrast 0.5..0.063 in three each, 0.032 missed three times
    assert plan.undrawable_logmar == [0.0]
    assert shown == 7 * 3 + 3 + 4 * 3 + 3
    app.wait("viewing")
    app.key("p")
    app.wait("pause")
    code, _ = app.quit_confirmed()
    assert code == 0

    [check] = read_session(study / "sessions" / "P01.sqlite").screenings
    assert check["test"] == "acuity" and check["outcome"] == "passed"
    result = check["result"]
    assert result["card_px"] == 425
    assert result["geometry"]["px_per_mm"] == pytest.approx(425 / 85.6)
    assert result["acuity"]["threshold_logmar"] == 0.2
    assert result["acuity"]["threshold_snellen"] == "20/32"
    assert result["contrast"]["threshold_weber"] == 0.063
    assert len(result["answers"]) == shown

    # The largest optotype on screen: a Landolt C 50 arcmin tall at 60 cm and 4.96 px/mm
    shot = np.asarray(Image.open(ARTIFACTS / "acuity-acuity-0.png").convert("L"))
    bg, fg, _ = grey_levels(0.9)
    h, w = shot.shape
    middle = shot[h // 4: 3 * h // 4, w // 4: 3 * w // 4]
    dark = np.abs(middle.astype(int) - fg) < 40
    rows, cols = np.flatnonzero(dark.any(axis=1)), np.flatnonzero(dark.any(axis=0))
    expected = 50 * geometry.px_per_arcmin
    assert rows[-1] - rows[0] + 1 == pytest.approx(expected, abs=1.5)
    assert cols[-1] - cols[0] + 1 == pytest.approx(expected, abs=1.5)
    assert np.median(middle) == bg  # drawn on the mid-grey of the stated contrast
    for name in ("acuity-card", "acuity-contrast-4"):
        assert (ARTIFACTS / f"{name}.png").is_file()


@pytest.mark.slow  # 11 s of GUI; CI runs it after make test
def test_a_failed_check_ends_the_session_when_the_study_says_so(tmp_path, xdisplay,
                                                                app_driver):
    study = _study(tmp_path, "end")
    app = app_driver(xdisplay, [str(study), "--participant", "P02", "--seed", "4",
                                "--practice", "0", "--pilot-no-vsync"])
    _start(app)
    app.key("Return")  # the 96 dpi start is accepted as it is
    app.wait("acuity-card-done width=324")
    plan = acuity_plan(card_calibration(324, 60), 4)
    app.wait("acuity-trials")
    app.key("space")
    _answer_all(app, plan, logmar=0.6, weber=0.25)
    app.wait("finishing screened_out=1")
    app.wait("end")  # the end screen takes keys once it says so
    app.key("Return")
    code, out = app.finish()
    assert code == 0 and "ended after the sharpness and contrast check" in out
    record = read_session(study / "sessions" / "P02.sqlite")
    [check] = record.screenings
    assert check["outcome"] == "failed"
    assert check["result"]["acuity"]["threshold_logmar"] == 0.6
    assert check["result"]["contrast"]["threshold_weber"] == 0.25
    assert record.info.finished_at is not None and record.ratings == []
    assert any(e["kind"] == "ended_by_vision_check" and e["test"] == "acuity"
               for e in record.events)
