"""Pilots (sessions the player paced on the clock, without vsync) are not participant data:
left out beside participants' sessions (``--include-pilots`` keeps them), analysed as they
are when alone and then called a pilot; a screening that needs more raters than there are
is said not to have run; a paced session's clock rate is not a display's refresh rate."""

from __future__ import annotations

import json

import pandas as pd
from support.cli import analyze
from support.sessions import player_session

from analysis.inputs import load_ratings
from analysis.presentation_text import _sessions
from analysis.quality import quality_table
from stimuli_manifests import load_manifest, parse_manifest, save_manifest


def _study(folder):
    refs = [{"id": f"R{i}", "path": f"r{i}.mkv"} for i in range(2)]
    conds = [{"id": f"R{i}_blur_L{lv}", "reference": f"R{i}", "path": f"r{i}_{lv}.mkv",
              "method": "blur", "level": lv} for i in range(2) for lv in (1, 2, 3)]
    return save_manifest(parse_manifest({
        "study_id": "piloted", "references": refs, "conditions": conds,
        "protocol": {"repetitions": 1}}), folder / "manifest.json")


def _sessions_of(folder, path, kinds: dict[str, str]):
    folder.mkdir(exist_ok=True)
    loaded = load_manifest(path)
    for k, (who, timing) in enumerate(kinds.items()):
        player_session(folder, loaded, who, timing=timing, seed=k + 1)
    return folder


def test_pilots_beside_participants_are_left_out_unless_asked(tmp_path):
    path = _study(tmp_path)
    folder = _sessions_of(tmp_path / "s", path, {
        "PILOT": "paced-pilot", "P1": "vsync", "P2": "vsync", "P3": "vsync"})
    rs = load_ratings(path, sessions=[folder])
    assert list(rs.raters) == ["P1", "P2", "P3"]
    pilots = [x for x in rs.exclusions if x.kind == "pilot session"]
    assert [x.who for x in pilots] == [str(folder / "PILOT.sqlite")]
    assert "--include-pilots keeps them" in pilots[0].rule
    kept = load_ratings(path, sessions=[folder], include_pilots=True)
    assert sorted(kept.raters) == ["P1", "P2", "P3", "PILOT"]
    # a pilot alone (or with simulated raters) is analysed as it is
    alone = _sessions_of(tmp_path / "alone", path, {"ME": "paced-pilot", "YOU": "paced-pilot"})
    assert sorted(load_ratings(path, sessions=[alone]).raters) == ["ME", "YOU"]


def test_a_pilots_report_says_so_and_that_two_raters_are_not_screened(tmp_path, capsys):
    path = _study(tmp_path)
    alone = _sessions_of(tmp_path / "alone", path, {"ME": "paced-pilot", "YOU": "paced-pilot"})
    out = tmp_path / "report"
    code, stdout, err = analyze(capsys, "report", "--manifest", path, "--sessions", alone,
                                "--model", "mos", "--bootstrap", "50", "--splits", "50",
                                "--out", out)
    assert code == 0, err
    assert "pilots used (paced without vsync, not participant data): ME, YOU" in stdout
    assert "rater screening (p913): not applied, it needs at least 3 raters" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["pilot_raters_used"] == ["ME", "YOU"]
    assert summary["screening_applied"] is False
    assert summary["minutes"]["n"] == 2 and summary["minutes"]["median"] < 1  # written at once
    assert "time in the study: median" in stdout
    text = (out / "methods.txt").read_text()
    assert text.startswith("[Not for a paper as it stands: 2 of the 2 raters ran pilots")
    assert "needs at least 3 raters and was not applied" in text
    assert "r2 on per-HRC means, needs 4 HRCs" not in text
    html = (out / "report.html").read_text()
    assert "2 of the 2 raters used are pilots, paced without vsync (ME, YOU)" in html
    assert "No rater screening: p913 needs at least 3 raters." in html
    # the paced sessions' 60 Hz is the clock's: no refresh rate is claimed for them
    assert "refreshed at" not in text

    # beside participants: left out, and said so on the terminal and the first screen
    mixed = _sessions_of(tmp_path / "mixed", path, {
        "PILOT": "paced-pilot", "P1": "vsync", "P2": "vsync", "P3": "vsync"})
    code, stdout, err = analyze(capsys, "report", "--manifest", path, "--sessions", mixed,
                                "--model", "mos", "--bootstrap", "50", "--splits", "50",
                                "--out", tmp_path / "r2")
    assert code == 0, err
    assert "pilot sessions left out (paced without vsync; --include-pilots keeps them): " \
           "PILOT.sqlite" in stdout
    assert "removed raters (p913):" in stdout  # three raters: screened
    html = (tmp_path / "r2" / "report.html").read_text()
    assert "1 pilot session(s) left out" in html


def test_include_pilots_needs_session_files(tmp_path, capsys):
    path = _study(tmp_path)
    pd.DataFrame({"participant": ["a", "b"], "stimulus": ["R0_blur_L1"] * 2,
                  "rating": [1.0, 2.0]}).to_csv(tmp_path / "r.csv", index=False)
    code, _, err = analyze(capsys, "dmos", "--manifest", path, "--ratings", tmp_path / "r.csv",
                           "--include-pilots", "--out", tmp_path / "d.csv")
    assert code == 2 and "--include-pilots needs session files" in err


def test_simulated_sessions_are_not_counted_as_displays():
    quality = pd.DataFrame({"timing_mode": ["vsync", "paced-pilot", "simulated", "simulated"],
                            "vsync": [True, False, None, None],
                            "presentations": [40, 40, 40, 40],
                            "trials_with_drops": [2, 30, 0, 0]},
                           index=["P1", "PILOT", "S1", "S2"])
    text = _sessions(quality, ["P1", "PILOT", "S1", "S2"])
    assert text.startswith(" The sessions of 1 of the 2 participants ran with vsync; 32 of "
                           "the 80 presentations in their session files (40.0%) dropped a "
                           "frame or more")
    assert "1 of them ran paced on the clock without vsync (pilots: PILOT)" in text
    assert "(2 simulated sessions, which had no display, are not counted)" in text


def test_the_refresh_rate_is_the_vsync_sessions(tmp_path):
    path = _study(tmp_path)
    folder = tmp_path / "s"
    folder.mkdir()
    loaded = load_manifest(path)
    player_session(folder, loaded, "P1", hz=143.9, timing="vsync", seed=1)
    player_session(folder, loaded, "P2", hz=60.0, timing="paced-pilot", seed=2)
    rs = load_ratings(path, sessions=[folder], include_pilots=True)
    q = quality_table(rs)
    assert q.loc["P1", "refresh_hz"] == 143.9
    assert pd.isna(q.loc["P2", "refresh_hz"])
