"""End to end: the real app on a virtual X display (Xvfb + Mesa), driven by real X input.

A tiny study (3 stimuli, 64x64, 1 s at 30 fps) is run with ``cgvq-study run`` in the
experimenter's pilot mode (Xvfb has no vsync; the session records ``paced-pilot``): display
check, briefing, consent, one practice trial, two rated trials (switching, mouse and keyboard
rating), pause and a confirmed quit; a resume during which a second run of the same
participant is refused, then killed with SIGKILL mid-trial; a final resume (taking over the
dead run's lock) to the end screen. The session file is then checked against what the input
events must have produced. Screenshots are kept under ``test-artifacts/study_app/e2e/``.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cgvq_cli.study_cli import main as cli_main
from session_store import SessionStore, read_ratings, verify_session
from stimuli_manifests import load_manifest, read_video

pytestmark = pytest.mark.gui

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "test-artifacts" / "study_app"
SCREEN = (1280, 1024)
PILOT = "--pilot-no-vsync"  # virtual displays have no vsync: the experimenter's test mode


def _slider(line: str) -> tuple[float, float, float]:
    x0, x1, y = (float(v) for v in re.search(r"slider=([\d.]+),([\d.]+),([\d.]+)",
                                             line).groups())
    return x0, x1, y


def _view_then_rate(app, trial: int) -> str:
    app.wait(f"viewing trial={trial}")
    return app.open_rating()  # the minimum viewing time is one loop (1 s)


def _ended(finished: tuple[int, str], says: str, lock: Path, session: Path) -> list[dict]:
    """The run exited with 0 saying ``says`` and released its lock; the session file reads
    without problems. Returns its rating rows."""
    code, out = finished
    assert code == 0, out
    assert says in out
    assert not lock.exists()
    rows, problems = read_ratings(session)
    assert problems == []
    return rows


def test_gui_session_end_to_end(tmp_path, xdisplay, study_factory, app_driver):
    study = study_factory(tmp_path / "study")
    session = study / "sessions" / "P01.sqlite"
    lock = study / "sessions" / "P01.sqlite.lock"
    shots = ARTIFACTS / "e2e"
    shutil.rmtree(shots, ignore_errors=True)
    args = [str(study), "--participant", "P01", "--seed", "5", "--max-dropped-frames", "-1",
            "--screenshots", str(shots), PILOT]

    # -- run 1: display check, briefing, consent, practice, two trials, pause, quit -------
    app = app_driver(xdisplay, [*args, "--practice", "1"])
    app.wait("preflight-passed")
    assert not study.joinpath("sessions", "P01.sqlite").exists()  # nothing stored yet
    app.key("space")
    app.wait("welcome")
    app.key("space")
    app.wait("consent")
    assert not session.exists()
    app.key("a")
    app.practice()

    app.switch_to_reference(0)
    time.sleep(1.2)  # the blank (0.5 s) is over: the reference shows for about 0.7 s
    app.key("space")
    app.wait("switch to=test")
    x0, x1, y = _slider(app.open_rating(min_view_s=0.5))
    app.click(x0 + 0.7 * (x1 - x0), y)
    app.wait("slider")
    time.sleep(0.2)
    app.key("Return")
    app.wait("recorded trial=0")

    _view_then_rate(app, 1)
    app.key("Right", "shift+Right", "shift+Right", "Left")  # 50, 60, 70, 69
    app.key("Return")
    app.wait("recorded trial=1")

    app.wait("viewing trial=2")
    app.key("p")
    app.wait("pause")
    app.key("q")
    app.wait("confirm-quit")  # quitting asks first; "no" goes back to the pause screen
    app.key("Escape")
    app.wait("pause")
    rows = _ended(app.quit_confirmed(), "2 of 3 trials answered", lock, session)
    assert [r["trial"] for r in rows] == [0, 1]
    assert rows[0]["rating"] == pytest.approx(70.0, abs=0.15)  # one pixel of the track
    assert rows[1]["rating"] == 69.0
    assert rows[0]["n_toggles"] == 2 and rows[1]["n_toggles"] == 0
    assert rows[0]["ms_on_reference"] > 500 and rows[0]["ms_on_test"] > 500
    assert rows[1]["ms_on_reference"] == 0
    assert all(r["rt_ms"] > 1000 for r in rows)
    with SessionStore.open(session) as store:
        logs = [p for p in store.presentations() if p["trial"] == 0]
        info = store.info
        events = store.events()
    kinds = [e["kind"] for e in events]
    assert len(logs) == 1
    lat = logs[0]["switch_latencies_ms"]
    # Each switch: a mid-grey blank of round(0.5 s x 60 Hz) = 30 refreshes of the presentation
    # clock (more only when frames were dropped), then the other video. Wall-clock figures
    # are loose here (shared CI machines); benchmarks/bench_player.py measures them properly.
    assert logs[0]["blank_target_refreshes"] == 30
    assert len(logs[0]["blank_refreshes"]) == 2 and min(logs[0]["blank_refreshes"]) >= 30
    assert len(lat) == 2 and all(400 < v < 3000 for v in lat)
    assert all(400 < v < 3000 for v in logs[0]["blank_durations_ms"])
    assert logs[0]["frames_presented"] > 60 and logs[0]["slider_first_move_ms"] > 1000
    assert logs[0]["timing_mode"] == "paced-pilot"
    # Xvfb has no vsync: the run was the experimenter's pilot mode, and the session says so.
    assert info.settings["timing_mode"] == "paced-pilot"
    assert info.display["vsync"] is False and info.display["timing_mode"] == "paced-pilot"
    assert info.display["window"] == list(SCREEN)
    assert info.display["monitors"] == 1 and info.display["monitor_index"] == 0
    assert info.display["screen"] == list(SCREEN) and info.display["pixel_ratio"] == 1.0
    assert {c["name"] for c in info.preflight} == {
        "screen_size", "refresh_rate", "pixel_mapping", "memory", "decode_speed", "checksums"}
    assert all(c["ok"] for c in info.preflight) and not info.preflight_skipped
    # Consent was recorded with the sha256 of the texts the participant saw (= the manifest's).
    texts = load_manifest(study / "manifest.json").manifest.texts
    consent = next(e for e in events if e["kind"] == "consent")
    assert consent["consent_sha256"] == texts["consent.md"]
    assert consent["briefing_sha256"] == texts["briefing.md"]
    assert kinds.index("preflight") < kinds.index("consent") < kinds.index("start")
    assert "pause" in kinds and "quit" in kinds
    # the practice trial is recorded as what was practised (a test video: the study_factory's
    # hidden references are never picked while test videos are left)
    practice = next(e for e in events if e["kind"] == "practice")
    assert len(practice["stimuli"]) == 1
    assert practice["stimuli"][0] in {str(c.id) for c in load_manifest(
        study / "manifest.json").manifest.conditions}
    assert cli_main(["verify", str(session)]) == 1  # intact but incomplete

    # -- run 2: resume; a second run of the same participant is refused; SIGKILL ----------
    app = app_driver(xdisplay, args)
    app.resume()
    app.wait("viewing trial=2")
    second = subprocess.run(
        [sys.executable, "-m", "cgvq_cli.study_cli", "run", *args],
        env={**xdisplay, "PYTHONPATH": str(REPO)}, capture_output=True, text=True, timeout=60)
    assert second.returncode == 2
    assert second.stderr.count("\n") == 1 and "already has a run open" in second.stderr
    time.sleep(0.3)
    os.kill(app.proc.pid, signal.SIGKILL)
    app.finish()
    rows, problems = read_ratings(session)
    assert problems == [] and len(rows) == 2
    assert lock.exists()  # left behind by the killed run, but no longer locked

    # -- run 3: takes the dead run's lock over, resumes at trial 2 and finishes -----------
    app = app_driver(xdisplay, args)
    app.resume()
    line = _view_then_rate(app, 2)
    x0, x1, y = _slider(line)
    bx, by, bw, bh = (float(v) for v in re.search(r"submit=([\d.,]+)", line).group(1).split(","))
    app.click(bx + bw / 2, by + bh / 2)  # Submit before the slider is set: nothing happens
    time.sleep(0.3)
    app.click(x0 + 0.2 * (x1 - x0), y)
    app.wait("slider")
    time.sleep(0.2)
    app.click(bx + bw / 2, by + bh / 2)
    app.wait("end")
    app.key("Return")
    rows = _ended(app.finish(), "Session finished: 3 trials", lock, session)
    assert [r["trial"] for r in rows] == [0, 1, 2]
    assert rows[2]["rating"] == pytest.approx(20.0, abs=0.15)
    manifest = load_manifest(study / "manifest.json").manifest
    assert sorted(r["stimulus"] for r in rows) == sorted(s.id for s in manifest.stimuli())
    report = verify_session(session)
    assert report.intact and report.complete
    assert cli_main(["verify", str(session)]) == 0

    # -- screenshots: the rating screen is not blank; the video is drawn 1:1 -----------
    rating = np.asarray(_png(shots / "rating-after-click.png"))
    assert rating.shape == (SCREEN[1], SCREEN[0], 3)
    assert rating.std() > 5
    red = (rating[..., 0] > 180) & (rating[..., 1] < 60) & (rating[..., 2] < 60)
    assert red.sum() > 100  # the slider's marker
    viewing = np.asarray(_png(shots / "test.png"))
    with SessionStore.open(session) as store:
        last = store.plan()[2]  # each run rewrites the shots: the last run showed trial 2
    frame0 = read_video(load_manifest(study / "manifest.json").stimulus_path(last.stimulus))[0]
    x, y = (SCREEN[0] - 64) // 2, (SCREEN[1] - 64) // 2
    np.testing.assert_array_equal(viewing[y:y + 64, x:x + 64], frame0)
    blank = np.asarray(_png(shots / "blank.png"))
    assert (blank[y:y + 64, x:x + 64] == 128).all()  # mid-grey where the video was


def _png(path: Path):
    from PIL import Image

    return Image.open(path).convert("RGB")


def test_gui_preflight_failure_says_what_to_change(tmp_path, xdisplay, study_factory,
                                                  app_driver):
    """A study that needs a bigger screen than Xvfb's stops with a message before briefing
    and consent, and leaves nothing behind: no session file, no lock, no sessions folder."""
    study = study_factory(tmp_path / "study", min_display=(1920, 1080))
    app = app_driver(xdisplay, [str(study), "--participant", "P02", "--practice", "0", PILOT])
    assert app.leave_failed_preflight("Escape") == 2
    err = " ".join(app.lines)
    assert "1280x1024" in err and "1920x1080" in err and "monitor" in err
    assert "--" not in err.split("pre-flight failed:", 1)[1]  # no command-line flag for them
    assert not any("state: welcome" in ln or "state: consent" in ln for ln in app.lines)
    assert not (study / "sessions").exists()


def test_gui_without_vsync_a_participant_run_stops_at_the_preflight(tmp_path, xdisplay,
                                                                    study_factory, app_driver):
    """Xvfb gives no vsync: without the experimenter's pilot flag the run stops at the
    pre-flight, telling the participant what to change on the computer."""
    study = study_factory(tmp_path / "study")
    app = app_driver(xdisplay, [str(study), "--participant", "P03"])
    assert app.leave_failed_preflight("Return") == 2
    err = " ".join(app.lines)
    assert "refresh_rate" in err and "vertical sync" in err and "graphics driver" in err
    assert "--" not in err.split("pre-flight failed:", 1)[1]
    assert not (study / "sessions").exists()


WARM_UP_PROBE = """
import numpy as np
from study_app.display import Display
from study_app.screens.draw import draw_viewing, warm_up_viewing
from study_app.layout import viewing_layout
d = Display(windowed=True, window_size=(800, 600), refresh_hz=60, force_pacer=True)
r = d.renderer
frames = np.zeros((3, 64, 64, 3), np.uint8)
tex = {"test": r.upload_video(frames), "reference": r.upload_video(frames)}
lay = viewing_layout(d.size, (64, 64), d.fonts, labels=["Test video", "Reference"],
                     progress="Trial 1 of 2", hints=["Space: switch", "Enter: rate"],
                     notice=["Please watch for at least", "1.0 s before rating"])
before = len(r._text_cache)
warm_up_viewing(r, lay, tex)
warmed = len(r._text_cache)
for content in ("test", "blank", "reference"):
    for notice in (False, True):
        for idx in range(3):
            draw_viewing(r, lay, tex.get(content), content, idx, notice=notice)
print(before, warmed, len(r._text_cache))
"""


def test_warm_up_makes_every_viewing_texture_before_the_first_flip(xdisplay):
    """A text texture made mid-trial costs a shader compile on Mesa (measured 45 ms): the
    warm-up must leave nothing new for the timed loop to create."""
    out = subprocess.run([sys.executable, "-c", WARM_UP_PROBE],
                         env={**xdisplay, "PYTHONPATH": str(REPO)}, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    before, warmed, after = (int(v) for v in out.stdout.split()[-3:])
    assert warmed - before >= 7  # two labels, the progress line, two hints, two notice lines
    assert after == warmed


ONE_TO_ONE_PROBE = """
import numpy as np
from study_app.display import Display
d = Display(windowed=True, window_size=(837, 679), refresh_hz=60, force_pacer=True)
r, ctx = d.renderer, d.ctx
W, H = d.window_size
for h, w in ((333, 501), (1, 3), (679, 837)):
    frames = np.random.default_rng(h).integers(0, 256, (3, h, w, 3), dtype=np.uint8)
    video = r.upload_video(frames)
    r.clear()
    x, y = r.draw_video(video, 2)
    ctx.finish()
    shown = np.frombuffer(ctx.screen.read(viewport=(x, H - y - h, w, h), components=3,
                                          alignment=1), np.uint8).reshape(h, w, 3)[::-1]
    print(h, w, int(np.array_equal(shown, frames[2])))
    video.release()
"""


def test_video_frames_are_drawn_one_to_one_at_odd_sizes(xdisplay):
    """Every texel lands on exactly one pixel, unfiltered, for sizes that are not powers of
    two and in an odd-sized window (the read-back must equal the decoded frame bit for bit)."""
    out = subprocess.run([sys.executable, "-c", ONE_TO_ONE_PROBE],
                         env={**xdisplay, "PYTHONPATH": str(REPO)}, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    rows = [line.split() for line in out.stdout.strip().splitlines()[-3:]]
    assert [r[2] for r in rows] == ["1", "1", "1"], rows


SDL_PROBE = """
import pygame
pygame.display.init()
from study_app import sdl
from study_app.keys import letter_scancode
print(sdl.layout_key_name(letter_scancode("q")), sdl.display_bounds(), sdl.display_name(0))
"""


def test_sdl_queries_monitor_and_keyboard_layout(xdisplay):
    """Monitor bounds and names, and the layout's key names, come from the SDL library
    Pygame loaded (Xvfb: one 1280x1024 screen, US layout)."""
    out = subprocess.run([sys.executable, "-c", SDL_PROBE],
                         env={**xdisplay, "PYTHONPATH": str(REPO)}, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    key, rest = out.stdout.strip().split(" ", 1)
    assert key == "Q"
    assert rest.startswith("[(0, 0, 1280, 1024)]")
