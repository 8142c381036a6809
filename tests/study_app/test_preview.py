"""``cgvq-study preview``: the participant's player on the experimenter's screen, nothing
recorded. The real app under Xvfb, driven by xdotool; screenshots kept as artifacts under
``test-artifacts/study_app/preview/``."""

from __future__ import annotations

import hashlib
import re
import shutil
import time
from pathlib import Path

import pytest

from cgvq_cli.study_cli import main as cli_main
from session_store.study_folder import load_study
from study_app.clock import FlipStats
from study_app.fonts import Fonts
from study_app.layout import GAP, Rect, viewing_layout
from study_app.preflight import Check
from study_app.preview import PreviewResult, PreviewRow, overlay_box, preview_trials
from study_app.screens.draw import LABEL_REFERENCE, LABEL_TEST

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "test-artifacts" / "study_app" / "preview"
ROW = re.compile(r"^  (\S+): (\d+) frames shown, (\d+) dropped(?: \([^)]*\))?, worst interval "
                 r"([\d.]+) ms; "
                 r"(rated ([\d.]+) \(not stored\)|stopped before rating)$")


def tree_digest(folder: Path) -> dict[str, str]:
    """Every file and folder under ``folder``, files with their sha256."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        out[rel] = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
    return out


def summary(out: str) -> tuple[str, list[re.Match], list[str], str]:
    """The printed summary: its timing line, the stimulus rows, pre-flight lines, verdict."""
    lines = out.splitlines()
    assert lines[0].startswith("preview of study tiny-study (nothing recorded):"), out
    body = [ln for ln in lines[1:] if ln.startswith("  ")]
    rows = [m for ln in body if (m := ROW.match(ln))]
    checks = [ln for ln in body if ln.startswith("  pre-flight ")]
    assert body[0].startswith("  timing: ") and body[-1].startswith("  verdict: "), out
    return body[0], rows, checks, body[-1]


@pytest.mark.gui
def test_preview_shows_the_pair_and_slider_and_records_nothing(tmp_path, xdisplay,
                                                               study_factory, app_driver):
    study = study_factory(tmp_path / "study")
    before = tree_digest(study)
    shots = ARTIFACTS
    shutil.rmtree(shots, ignore_errors=True)
    started = time.monotonic()
    app = app_driver(xdisplay, [str(study), "--timing-overlay", "--screenshots", str(shots),
                                "--windowed", "--window-size", "1024x768"],
                     subcommand="preview")
    app.wait("preview-intro")
    app.key("space")
    trials = preview_trials(load_study(study), None)
    for _ in trials:
        app.wait("viewing")
        time.sleep(0.3)  # the overlay's figures are renewed four times a second
        app.key("space")  # to the reference (after the blank)
        app.wait("switch to=reference")
        app.open_rating(min_view_s=1.0)
        app.key("Right", "Right", "Return")
        app.wait("previewed")
    app.wait("preview-end")
    app.key("Return")
    code, out = app.finish()
    assert code == 0, app.lines[-10:]
    timing, rows, checks, verdict = summary(out)
    n = len(trials)
    assert f"{n} of {n} stimuli previewed" in timing and "paced" in timing
    assert [m.group(1) for m in rows] == [t.stimulus for t in trials]  # the preview's order
    for m in rows:
        assert int(m.group(2)) > 30 and int(m.group(3)) >= 0 and float(m.group(4)) > 10
        assert float(m.group(6)) == pytest.approx(51.0, abs=1.5)  # a click-free 50 + 2 steps
    assert {c.split(":")[0] for c in checks} == {
        f"  pre-flight {c}" for c in ("screen_size", "refresh_rate", "pixel_mapping", "memory",
                                      "decode_speed", "checksums")}
    assert "  pre-flight checksums: ok" in "\n".join(checks)
    pace = re.search(r"  pace: median ([\d.]+) s per stimulus from its start to the rating "
                     rf"\({n} rated\); a participant's session of (\d+) trials", out)
    assert pace, out
    assert 1.0 < float(pace.group(1)) < time.monotonic() - started  # at least the min view
    assert int(pace.group(2)) == n  # every stimulus once: 1 repetition
    assert "verdict: " in verdict
    # nothing written into the study folder: no sessions/, no lock, same bytes
    assert tree_digest(study) == before
    for name in ("preview-intro", "preview-test", "preview-blank", "preview-reference",
                 "preview-rating-before-click", "preview-rating-after-click", "preview-end"):
        assert (shots / f"{name}.png").is_file(), sorted(p.name for p in shots.iterdir())


@pytest.mark.gui
def test_esc_stops_early_and_still_sums_up(tmp_path, xdisplay, study_factory, app_driver):
    """One stimulus (--stimulus), paced at 50 Hz (--no-vsync --refresh-hz), stopped with Esc
    while it plays: its timing is still listed, unrated, and nothing was written."""
    study = study_factory(tmp_path / "study")
    other = load_study(study).loaded.stimulus_path("SRC01_HRC01")  # not previewed, damaged
    other.write_bytes(other.read_bytes()[:-1] + b"\x00")
    before = tree_digest(study)
    shots = ARTIFACTS.with_name("preview-stop")
    shutil.rmtree(shots, ignore_errors=True)
    app = app_driver(xdisplay, [str(study), "--stimulus", "SRC01_HRC02", "--windowed",
                                "--no-vsync", "--refresh-hz", "50", "--timing-overlay",
                                "--pilot-no-vsync", "--screenshots", str(shots)],
                     subcommand="preview")
    app.wait("preview-intro")
    app.key("Return")
    app.wait("viewing")
    time.sleep(0.6)
    app.key("Escape")
    app.wait("preview-pause")
    app.key("Escape")
    app.wait("preview-end")
    app.key("Escape")
    code, out = app.finish()
    assert code == 0, app.lines[-10:]
    timing, rows, checks, verdict = summary(out)
    assert "0 of 1 stimuli previewed, 1 stopped early" in timing and "50.00 Hz" in timing
    # a participant's run would refuse the damaged file: the preview says so, reported only
    assert any(c.startswith("  pre-flight checksums: not met (reported only)")
               for c in checks), checks
    assert len(rows) == 1 and rows[0].group(1) == "SRC01_HRC02"
    assert rows[0].group(5) == "stopped before rating" and int(rows[0].group(2)) > 10
    assert "paced on the clock" in verdict or "dropped frame(s)" in verdict
    assert tree_digest(study) == before
    assert (shots / "preview-pause.png").is_file() and (shots / "preview-end.png").is_file()


@pytest.mark.gui
def test_videos_larger_than_the_window_are_refused(tmp_path, xdisplay, study_factory,
                                                   app_driver):
    study = study_factory(tmp_path / "study", size=640, seconds=0.2)
    before = tree_digest(study)
    app = app_driver(xdisplay, [str(study), "--window-size", "800x600"], subcommand="preview")
    code, out = app.finish()
    assert code == 2 and out == ""
    err = [ln for ln in app.lines if "error" in ln]
    assert err and "do not fit into the window (800x600 pixels)" in err[-1]
    assert tree_digest(study) == before


@pytest.mark.parametrize(("args", "says"), [
    (["--stimulus", "nope"], "'nope' is not a stimulus of study tiny-study (e.g. SRC01"),
    (["--window-size", "640x480"], "--window-size 640x480 is too small"),
    (["--refresh-hz", "5"], "--refresh-hz must be between 20 and 500"),
    (["--screenshots", "{study}/shots"], "outside the study folder"),
    (["--missing"], "1 video file(s) of the study are missing: "),
])
def test_user_errors_are_one_line_before_any_window(tmp_path, study_factory, capsys, args,
                                                    says):
    study = study_factory(tmp_path / "study")
    if args == ["--missing"]:  # refused before a window, not when the preview reaches it
        load_study(study).loaded.stimulus_path("SRC01_HRC02").unlink()
        args = []
    before = tree_digest(study)
    code = cli_main(["preview", str(study), *(a.format(study=study) for a in args)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and says in err[0], err
    assert tree_digest(study) == before


@pytest.mark.parametrize("window", [(800, 600), (1024, 768), (1920, 1080)])
def test_the_overlay_keeps_off_the_video_and_the_texts(window):
    lay = viewing_layout(window, (256, 256), Fonts(), labels=[LABEL_TEST, LABEL_REFERENCE],
                         progress="Trial 1 of 3", hints=["Space: switch", "Enter: rate",
                                                         "P: pause"],
                         notice=["Please watch for at least", "1.0 s before rating"])
    box = overlay_box(lay, (220, 60), window)
    assert box is not None and box.inside(*window)
    v = lay.video
    assert not box.intersects(Rect(v.x - GAP, v.y - GAP, v.w + 2 * GAP, v.h + 2 * GAP))
    for taken in [*lay.text_rects(), *([lay.label] if lay.label else [])]:
        assert not box.intersects(taken)
    assert overlay_box(lay, (window[0], window[1]), window) is None  # no room: not drawn


def test_the_overlay_finds_a_free_spot_off_the_corners():
    """A video filling the window's height: no corner free of text, a spot beside it is."""
    window = (1600, 1024)
    lay = viewing_layout(window, (1000, 1000), Fonts(), labels=[LABEL_TEST, LABEL_REFERENCE],
                         progress="Trial 1 of 3", hints=["Space: switch"], notice=["Wait"])
    box = overlay_box(lay, (200, 60), window)
    assert box is not None and not box.intersects(lay.video)
    assert all(not box.intersects(t) for t in lay.text_rects())


def _stats(intervals_ms: list[float]) -> FlipStats:
    s = FlipStats(1 / 60)
    t = 0.0
    s.add(t)
    for iv in intervals_ms:
        t += iv / 1000
        s.add(t)
    return s


def test_summary_adds_up_restarts_and_says_what_it_means():
    row = PreviewRow("SRC01_HRC01")
    row.add(_stats([16.7] * 10 + [40.0]))  # paused once, then shown again
    row.add(_stats([16.7] * 5))
    row.rating = 42.0
    other = PreviewRow("SRC01")
    other.add(_stats([16.7] * 3))
    res = PreviewResult("vsync", 59.95, [row, other], total=3,
                        checks=[Check("screen_size", False, "too small")])
    lines = res.lines()
    assert lines[0] == ("timing: vsync at 59.95 Hz; 1 of 3 stimuli previewed, 1 stopped early; "
                        "1 dropped frame(s) in all")
    assert lines[1] == ("SRC01_HRC01: 18 frames shown, 1 dropped (1 refresh missed), worst "
                        "interval 40.0 ms; rated 42.0 (not stored)")
    assert lines[2].endswith("stopped before rating")
    assert lines[3].startswith("pace: ")
    assert lines[4] == "pre-flight screen_size: not met (reported only): too small"
    assert lines[-1].startswith("verdict: 1 dropped frame(s) in 1 of 2 stimuli")
    clean = PreviewResult("vsync", 60.0, [other], total=1)
    assert "shows the study cleanly" in clean.verdict()
    assert "needs vsync" in PreviewResult("paced-pilot", 60.0, [other], total=1).verdict()
    assert PreviewResult("vsync", 60.0, [], total=1).verdict() == "verdict: no stimulus was shown"


def test_the_pace_tells_how_long_a_whole_session_takes():
    """Rated in 10, 30 and 20 s (one stopped unrated after 90 s): median 20 s, so a
    session of 240 trials takes 80 min, told beside what participants are told."""
    rows = [PreviewRow(f"S{i}", rating=50.0, seconds=s) for i, s in enumerate((10, 30, 20))]
    rows.append(PreviewRow("S9", seconds=90.0))
    res = PreviewResult("vsync", 60.0, rows, total=4, session_trials=240,
                        told="about 50-90 min")
    assert res.pace() == ("pace: median 20.0 s per stimulus from its start to the rating "
                          "(3 rated); a participant's session of 240 trials takes about 80 min "
                          "at this pace, breaks aside (participants are told about 50-90 min)")
    assert res.pace() in res.lines()
    rows[3].rating = 1.0
    assert "median 25.0 s" in res.pace()  # even count: the mean of the middle two
    assert PreviewResult("vsync", 60.0, [PreviewRow("S0")], total=1).pace() is None


def test_a_freeze_counts_the_refreshes_it_hid_as_a_run_does():
    """A 1 s freeze at 60 Hz is one late flip but 59 missed refreshes: a participant's run
    re-queues that trial (more than 10), and the preview used to say "1 dropped"."""
    frozen = PreviewRow("SRC01_HRC02")
    frozen.add(_stats([1000 / 60] * 30 + [1000.0] + [1000 / 60] * 30))
    assert (frozen.dropped_frames, frozen.missed_refreshes) == (1, 59)
    assert "1 dropped (59 refreshes missed; a run would re-queue it)" in frozen.line()
    verdict = PreviewResult("vsync", 60.0, [frozen], total=1).verdict()
    assert "a run would re-queue SRC01_HRC02 (more than 10 refreshes missed)" in verdict


def test_a_video_that_stops_decoding_mid_way_keeps_the_summary(tmp_path, study_factory,
                                                                capsys, monkeypatch):
    """The summary of what was previewed is printed, then one line on stderr, exit 2."""
    from study_app import preview as preview_module

    study = study_factory(tmp_path / "study")
    row = PreviewRow("SRC01_HRC01")
    row.add(_stats([16.7] * 20))
    row.rating = 50.0
    done = PreviewResult("vsync", 60.0, [row], total=3,
                         failure="cannot decode stimulus SRC01_HRC02 (truncated)")
    monkeypatch.setattr(preview_module, "run_preview", lambda study, opts: done)
    code = cli_main(["preview", str(study)])
    out, err = capsys.readouterr()
    assert code == 2 and "SRC01_HRC01: 21 frames shown" in out
    assert "verdict: stopped, cannot decode stimulus SRC01_HRC02" in out
    assert err.count("\n") == 1 and "the preview stopped: cannot decode" in err


def test_the_overlay_names_the_stimulus_on_screen_first():
    """Judging the levels in a preview, the experimenter could not tell which video was on."""
    from types import SimpleNamespace

    from study_app.preview import OVERLAY_TEMPLATE, TimingOverlay

    display = SimpleNamespace(size=(1024, 768), refresh_hz=60.0, vsync=False)
    overlay = TimingOverlay(display, PreviewResult("paced", 60.0))
    overlay._start(SimpleNamespace())
    overlay.stimulus = "sponza_ours_L64"
    lines = overlay.text(None)
    assert lines[0] == "sponza_ours_L64" and lines[1].startswith("frame ")
    assert len(lines) == len(OVERLAY_TEMPLATE)  # the box is sized for every line
