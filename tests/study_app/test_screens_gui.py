"""Every participant screen, at 800x600 and at 1920x1080, from the real app on Xvfb.

Each screen's first frame is saved under ``test-artifacts/study_app/screens/<W>x<H>/`` (look
at them). The videos are single flat colours no text uses, so the pixels prove what the layout
rectangles promise: inside the video rectangle there is nothing but the video (1:1, no text),
during the blank nothing but mid-grey.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from support.sessions import plain_result

from session_store import SessionStore
from session_store.schedule import make_schedule, schedule_items
from session_store.study_folder import load_study
from stimuli_manifests import (
    fill_checksums,
    load_manifest,
    parse_manifest,
    save_manifest,
    write_video,
)
from study_app.app import App, RunOptions
from study_app.layout import video_rect
from study_app.screens.draw import REFERENCE_LINE, TEST_FILL

pytestmark = pytest.mark.gui

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "test-artifacts" / "study_app" / "screens"
PILOT = "--pilot-no-vsync"
# Flat video colours that no text, label or button uses.
COLOURS = {"ref0.mkv": (41, 103, 231), "c1.mkv": (231, 29, 201), "c2.mkv": (29, 201, 129)}
SIZES = {(800, 600): (480, 360), (1920, 1080): (1024, 1024)}
SCREENS = ["preflight-passed", "preflight-failed", "welcome", "consent", "seating", "practice",
           "practice-trial", "practice-end", "test", "blank", "reference",
           "rating-before-click", "rating-after-click", "pause", "confirm-withdraw",
           "confirm-quit", "break", "welcome-back", "end"]

BRIEFING = """# Welcome to the study

You will watch short **computer-graphics videos** and rate how *annoying* their distortions
are compared with the original.

## Before you start

- Sit at a normal distance from the screen, in a room that is not too bright.
- Close other programs, and keep the study **full screen**.
- There are no right or wrong answers: we want *your* impression.
"""
CONSENT = "# Consent to take part\n\n" + "\n\n".join(
    f"{i}. **Point {i}.** I understand that my ratings, the time I take and the settings of my "
    "screen are stored with a participant number, not with my name, and that I can stop at "
    "any time without giving a reason." for i in range(1, 9))


def _make_study(folder: Path, video: tuple[int, int], min_display: tuple[int, int]) -> Path:
    w, h = video
    for name, colour in COLOURS.items():
        frames = np.empty((10, h, w, 3), np.uint8)
        frames[:] = colour
        write_video(folder / "videos" / name, frames, 10)
    (folder / "briefing.md").write_text(BRIEFING, encoding="utf-8")
    (folder / "consent.md").write_text(CONSENT, encoding="utf-8")
    manifest = parse_manifest({
        "study_id": "screens", "root": "videos",
        "protocol": {"repetitions": 1, "blank_seconds": 0.5, "viewing_distance_cm": 70},
        "display": {"min_width": min_display[0], "min_height": min_display[1],
                    "min_refresh_hz": 59},
        "references": [{"path": "ref0.mkv", "width": w, "height": h, "fps": 10,
                        "frames": 10}],
        "conditions": [{"reference": "SRC01", "method": "noise", "level": lv, "path": p}
                       for lv, p in ((1, "c1.mkv"), (2, "c2.mkv"))],
    })
    save_manifest(manifest, folder / "manifest.json")
    save_manifest(fill_checksums(load_manifest(folder / "manifest.json")),
                  folder / "manifest.json")
    return folder


def _half_done_session(study_dir: Path, participant: str, answered: int) -> None:
    """A session of ``participant`` with its first ``answered`` trials rated, as a participant
    who stopped halfway leaves it."""
    study = load_study(study_dir)
    path = App(study, RunOptions(participant=participant)).session_path
    plan = make_schedule(schedule_items(study.manifest), study.manifest.protocol.repetitions, 3)
    with SessionStore.create(path, participant=participant, study_id=study.manifest.study_id,
                             manifest_sha256=study.loaded.sha256, seed=3, app_version="t",
                             plan=plan) as store:
        for trial in plan[:answered]:
            store.record(trial.index, plain_result(50.0))


def _rate(app) -> None:
    app.open_rating()
    app.key("Right", "Return")


def _png(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


# 24 s at 800x600 and 35 s at 1920x1080: CI runs both after `make test` (.ci/run), as does
# `make test-slow`, and keeps their screenshots
@pytest.mark.slow
@pytest.mark.parametrize("screen", list(SIZES), ids=lambda s: f"{s[0]}x{s[1]}")
def test_every_screen_fits_and_never_draws_on_the_video(tmp_path, xvfb_factory, app_driver,
                                                        screen):
    video = SIZES[screen]
    env = xvfb_factory(screen)
    study = _make_study(tmp_path / "study", video, screen)
    shots = ARTIFACTS / f"{screen[0]}x{screen[1]}"
    shutil.rmtree(shots, ignore_errors=True)
    base = [str(study), "--participant", "P01", "--seed", "3", "--break-every", "1",
            "--max-dropped-frames", "-1", "--screenshots", str(shots), PILOT]

    # -- a new session up to a pause, a withdraw that is called off, and a quit ------------
    app = app_driver(env, [*base, "--practice", "1"])
    app.wait("preflight-passed")
    app.key("space")
    app.wait("welcome")
    app.key("space")
    app.wait("consent")
    if screen[1] < 800:  # the consent is longer than the screen: accepting needs reading it
        app.key("a")
        app.wait("consent-scroll")
    app.key("End", "a")
    app.wait("seating")
    app.key("space")
    app.wait("practice")
    app.key("space")
    app.wait("viewing trial=-1 practice=1")
    _rate(app)
    app.wait("practice-end")
    app.key("space")
    app.switch_to_reference(0)
    app.open_rating()
    time.sleep(0.3)
    app.key("Right")
    app.wait("slider")
    time.sleep(0.3)
    app.key("Return")
    app.wait("break")
    app.key("space")
    app.wait("viewing trial=1")
    app.key("p")
    app.wait("pause")
    app.key("w")
    app.wait("confirm-withdraw")
    app.key("Escape")
    app.wait("pause")
    code, out = app.quit_confirmed()
    assert code == 0, out

    # -- resume to the end ---------------------------------------------------------------
    app = app_driver(env, base)
    app.resume()
    app.wait("seating")  # where to sit, again, before the first trial of a return
    app.key("space")
    app.wait("viewing trial=1")
    _rate(app)
    app.wait("break")
    app.key("space")
    app.wait("viewing trial=2")
    _rate(app)
    app.wait("end")
    app.key("Return")
    code, out = app.finish()
    assert code == 0 and "Session finished: 3 trials" in out, out

    # -- a display that fails the check ----------------------------------------------------
    big = _make_study(tmp_path / "big", video, (screen[0] + 640, screen[1] + 360))
    app = app_driver(env, [str(big), "--participant", "P02", "--screenshots", str(shots),
                           PILOT])
    assert app.leave_failed_preflight("Escape") == 2
    # ... and a resumed session there: the screen says the answers so far are kept
    _half_done_session(big, "P03", answered=1)
    resumed = shots / "resumed"
    app = app_driver(env, [str(big), "--participant", "P03", "--screenshots", str(resumed),
                           PILOT])
    assert app.leave_failed_preflight("Escape") == 2
    assert (resumed / "preflight-failed.png").exists()
    assert not np.array_equal(_png(resumed / "preflight-failed.png"),
                              _png(shots / "preflight-failed.png"))

    missing = [s for s in SCREENS if not (shots / f"{s}.png").exists()]
    assert not missing, missing

    rect = video_rect(screen, video)
    x, y, w, h = rect.as_tuple()
    colours = {tuple(c) for c in COLOURS.values()}
    for name in ("test", "reference", "practice-trial"):
        img = _png(shots / f"{name}.png")
        assert img.shape == (screen[1], screen[0], 3)
        inside = img[y:y + h, x:x + w].reshape(-1, 3)
        # Exactly one flat video colour inside the video's rectangle: no text pixel there.
        assert len(np.unique(inside, axis=0)) == 1, name
        assert tuple(inside[0]) in colours, name
    blank = _png(shots / "blank.png")
    assert (blank[y:y + h, x:x + w] == 128).all()
    # The label beside the video says which one shows, by colour and kind, not only by word.
    test_img, ref_img = _png(shots / "test.png"), _png(shots / "reference.png")
    assert _has(test_img, TEST_FILL) and not _has(test_img, REFERENCE_LINE)
    assert _has(ref_img, REFERENCE_LINE) and not _has(ref_img, TEST_FILL)
    # No marker until the first click or key; then the red marker.
    assert not _has(_png(shots / "rating-before-click.png"), (0.85, 0.10, 0.10, 1))
    assert _has(_png(shots / "rating-after-click.png"), (0.85, 0.10, 0.10, 1))
    for name in SCREENS:
        img = _png(shots / f"{name}.png")
        assert img.shape == (screen[1], screen[0], 3) and img.std() > 1, name  # not empty


def _has(img: np.ndarray, colour: tuple[float, ...], min_pixels: int = 50) -> bool:
    target = np.array([round(255 * c) for c in colour[:3]])
    return int((np.abs(img.astype(int) - target).max(axis=-1) <= 2).sum()) >= min_pixels
