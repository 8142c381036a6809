"""``cgvq-study preview``: the participant's player on the experimenter's screen, nothing
recorded. The real app under Xvfb, driven by xdotool; screenshots kept as artifacts."""

from __future__ import annotations

import hashlib
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from session_store.study_folder import load_study
from study_app.fonts import Fonts
from study_app.layout import Rect, viewing_layout
from study_app.preview import overlay_box, preview_trials
from study_app.screens.draw import LABEL_REFERENCE, LABEL_TEST

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "test-artifacts" / "study_app" / "preview"


def tree_digest(folder: Path) -> dict[str, str]:
    """Every file (and empty folder) under ``folder`` with its sha256."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        out[rel] = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
    return out


@pytest.mark.gui
def test_preview_shows_the_pair_and_slider_and_records_nothing(tmp_path, xdisplay,
                                                               study_factory, app_driver):
    study = study_factory(tmp_path / "study")
    before = tree_digest(study)
    shots = ARTIFACTS
    shutil.rmtree(shots, ignore_errors=True)
    app = app_driver(xdisplay, [str(study), "--timing-overlay", "--screenshots", str(shots),
                                "--windowed", "--window-size", "1024x768"],
                     subcommand="preview")
    app.wait("preview-intro")
    app.key("space")
    n = len(preview_trials(load_study(study), None))
    for _ in range(n):
        app.wait("viewing")
        app.key("space")  # to the reference (after the blank)
        app.wait("switch to=reference")
        app.open_rating(min_view_s=1.0)
        app.key("Right", "Right", "Return")
        app.wait("previewed")
    app.wait("preview-end")
    app.key("Return")
    code, out = app.finish()
    assert code == 0, app.lines[-10:]
    lines = [ln for ln in out.splitlines() if ln.startswith("  ")]
    assert lines[0].strip().startswith("timing: ")
    assert f"{n} of {n} stimuli previewed" in lines[0]
    rows = lines[1:]
    assert len(rows) == n
    for row in rows:
        m = re.search(r": (\d+) frames shown, (\d+) dropped, worst interval ([\d.]+) ms; "
                      r"rated ([\d.]+) \(not stored\)", row)
        assert m and int(m.group(1)) > 30 and float(m.group(4)) == pytest.approx(51.0, abs=1.5)
    # nothing written into the study folder: no sessions/, no lock, same bytes
    assert tree_digest(study) == before
    for name in ("preview-intro", "preview-test", "preview-reference",
                 "preview-rating-after-click", "preview-end"):
        assert (shots / f"{name}.png").is_file(), sorted(p.name for p in shots.iterdir())


def test_unknown_stimulus_is_one_line(tmp_path, study_factory):
    study = study_factory(tmp_path / "study")
    res = subprocess.run([sys.executable, "-m", "cgvq_cli.study_cli", "preview", str(study),
                          "--stimulus", "nope"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "'nope' is not a stimulus" in res.stderr
    res = subprocess.run([sys.executable, "-m", "cgvq_cli.study_cli", "preview", str(study),
                          "--screenshots", str(study / "shots")], capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 2 and "outside the study folder" in res.stderr
    assert not (study / "shots").exists()


@pytest.mark.parametrize("window", [(800, 600), (1024, 768), (1920, 1080)])
def test_the_overlay_keeps_off_the_video_and_the_texts(window):
    lay = viewing_layout(window, (256, 256), Fonts(), labels=[LABEL_TEST,
                                                                     LABEL_REFERENCE],
                         progress="Trial 1 of 3", hints=["Space: switch", "Enter: rate",
                                                         "P: pause"],
                         notice=["Please watch for at least", "1.0 s before rating"])
    box = overlay_box(lay, (220, 60), window)
    assert box is not None and box.inside(*window)
    for taken in [lay.video, *lay.text_rects(), *([lay.label] if lay.label else [])]:
        assert not box.intersects(taken)
    assert overlay_box(lay, (window[0], window[1]), window) is None  # no room: not drawn
    assert isinstance(box, Rect)
