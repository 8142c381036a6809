"""The reporting items a reviewer asks for, stated from the session files and the manifest:
the videos' size, length and frame rate and their visual angle, the refresh rates that could
not show the frame rates evenly, practice, order, breaks and time, the participant flow with
withdrawals, and the display of the session whose ratings were used. Expected values come
from the sessions the test writes and from the acuity module's own geometry."""

from __future__ import annotations

import pandas as pd
from support.sessions import player_session

from analysis.inputs import load_ratings
from analysis.presentation_text import presentation_paragraph, uneven_refresh
from analysis.quality import quality_table
from analysis.sessions import withdrawn_participants
from stimuli_manifests import load_manifest, parse_manifest, save_manifest


def _study(folder, fps=(30, 60)):
    refs = [{"id": f"R{i}", "path": f"r{i}.mkv", "width": 256, "height": 144, "fps": f,
             "frames": 3 * f} for i, f in enumerate(fps)]
    conds = [{"id": f"R{i}_blur_L{lv}", "reference": f"R{i}", "path": f"r{i}_{lv}.mkv",
              "method": "blur", "level": lv} for i in range(len(fps)) for lv in (1, 2)]
    return save_manifest(parse_manifest({
        "study_id": "items", "references": refs, "conditions": conds,
        "protocol": {"repetitions": 1, "viewing_distance_cm": 60}}), folder / "manifest.json")


def test_uneven_refresh_rates():
    assert not uneven_refresh(60.0, [30, 60]) and not uneven_refresh(120.0, [30, 60])
    assert not uneven_refresh(59.94, [60]) and not uneven_refresh(240.0, [30, 60])
    assert uneven_refresh(144.0, [30, 60])  # 4.8 and 2.4 refreshes per frame
    assert uneven_refresh(75.0, [30]) and not uneven_refresh(75.0, [25])
    assert uneven_refresh(50.0, [60])  # fewer refreshes than frames: frames skipped


def test_the_stimuli_the_cadence_the_angle_and_the_session_order(tmp_path):
    from study_app.vision.acuity import card_calibration

    path = _study(tmp_path)
    loaded = load_manifest(path)
    s = tmp_path / "s"
    s.mkdir()
    common = {"practice": 2, "break_every": 40}
    player_session(s, loaded, "P1", hz=60.0, card_px=300, **common)
    player_session(s, loaded, "P2", hz=144.0, card_px=420, seed=2, **common)
    player_session(s, loaded, "P3", hz=75.0, seed=3, **common)
    rs = load_ratings(path, sessions=[s])
    text = presentation_paragraph(rs, quality_table(rs), ["P1", "P2", "P3"])
    assert "The videos were 256x144 pixels and 3 s long, at 30 and 60 frames per second." \
        in text
    assert ("On the screens of 2 of the 3 participants whose refresh rate was measured "
            "(75-144 Hz) it was not a whole multiple of the videos' 30 and 60 fps") in text
    # the acuity check measured at 60 cm, the seating is 60 cm: its own pixels per degree
    deg = sorted(256 / card_calibration(px, 60).px_per_degree for px in (300, 420))
    assert (f"The videos (256 pixels wide) thus spanned {deg[0]:.1f}-{deg[1]:.1f} degrees of "
            f"visual angle horizontally (median {(deg[0] + deg[1]) / 2:.1f}).") in text
    assert ("2 practice trials (not rated) came first; each participant saw the trials in "
            "their own random order, never the same stimulus twice in a row; a break was "
            "offered every 40 trials.") in text
    assert "The participants spent " in text and "in the study, breaks included." in text
    even = presentation_paragraph(rs, quality_table(rs), ["P1"])
    assert "Every measured refresh rate was a whole multiple of 30 and 60 fps" in even


def test_the_display_is_that_of_the_session_holding_the_ratings(tmp_path):
    """A participant's second session (a copy of the plan run again on another screen, all
    its ratings duplicates of the first's) does not replace the first session's display."""
    path = _study(tmp_path, fps=(60,))
    loaded = load_manifest(path)
    s = tmp_path / "s"
    s.mkdir()
    player_session(s, loaded, "P1", hz=144.0, seed=1)
    second = player_session(s, loaded, "P1", hz=60.0, seed=5, name="P1-again")
    import sqlite3

    with sqlite3.connect(second) as con:  # fewer ratings there: drop all but one
        con.execute("PRAGMA foreign_keys=OFF")
        keep = con.execute("SELECT min(seq) FROM ratings").fetchone()[0]
        con.execute("DELETE FROM ratings WHERE seq > ?", (keep,))
    rs = load_ratings(path, sessions=[s])
    assert float(rs.rater_info.loc["P1", "refresh_hz"]) == 144.0


def test_a_withdrawal_is_in_the_participant_flow(tmp_path, capsys):
    from support.cli import analyze

    path = _study(tmp_path)
    loaded = load_manifest(path)
    s = tmp_path / "s"
    s.mkdir()
    for k in range(4):
        player_session(s, loaded, f"P{k + 1}", seed=k + 1)
    player_session(s, loaded, "P5", seed=9, withdraw=True)
    rs = load_ratings(path, sessions=[s])
    assert withdrawn_participants(rs.exclusions) == ["P5"] and "P5" not in rs.raters
    out = tmp_path / "r"
    code, _, err = analyze(capsys, "report", "--manifest", path, "--sessions", s, "--model",
                           "mos", "--outliers", "none", "--bootstrap", "20", "--splits", "20",
                           "--out", out)
    assert code == 0, err
    methods = (out / "methods.txt").read_text()
    assert methods.startswith("5 participants took part and 1 withdrew (none of their "
                              "ratings or answers was used); the other 4 gave valid ratings. "
                              "The study had 6 stimuli (2 source contents; 2 distortion "
                              "conditions: blur at 2 levels; 4 processed sequences; 2 hidden "
                              "references)")
    quality = pd.read_csv(out / "tables" / "data_quality.csv", index_col="rater")
    assert list(quality["practice_trials"].isna()) == [True] * len(quality)  # not stored


def test_simulated_raters_have_no_order_or_time_to_report():
    from analysis.presentation_text import _order

    quality = pd.DataFrame({"timing_mode": ["simulated", "simulated", "vsync"],
                            "practice_trials": [2, 2, 3], "break_every": [40, 40, 20],
                            "minutes": [0.1, 0.1, 31.0]}, index=["S1", "S2", "P1"])
    assert _order(quality, ["S1", "S2"]) == ""
    assert _order(quality, ["S1", "S2", "P1"]) == (
        " 3 practice trials (not rated) came first; each participant saw the trials in their "
        "own random order, never the same stimulus twice in a row; a break was offered every "
        "20 trials. The participants spent 31 min in the study, breaks included.")
