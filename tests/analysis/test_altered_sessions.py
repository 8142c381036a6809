"""A session file changed outside the app after it was recorded: its ratings before the
change are authentic and used, and the report says the file was altered. It used to call
such a rater "partial" ("answered less than 50% of their trials", "an incomplete session was
kept"), which a reader takes for a participant who stopped early."""

from __future__ import annotations

import sqlite3

import pandas as pd
from support.cli import analyze
from support.sessions import blur_manifest, player_session

from stimuli_manifests import load_manifest


def _study(folder):
    return blur_manifest(folder, "altered")


def test_an_altered_file_is_named_as_altered_not_as_partial(tmp_path, capsys):
    path = _study(tmp_path)
    loaded = load_manifest(path)
    s = tmp_path / "s"
    s.mkdir()
    files = {p: player_session(s, loaded, p, seed=k + 1)
             for k, p in enumerate(("P1", "P2", "P3", "P4", "P5"))}
    with sqlite3.connect(files["P4"]) as con:  # the second rating edited: 1 of 6 authentic
        con.execute("UPDATE ratings SET rating = rating + 1 WHERE seq = 2")
    with sqlite3.connect(files["P5"]) as con:  # the last rating removed: 5 of 6 authentic
        con.execute("PRAGMA foreign_keys=OFF")
        con.execute("DELETE FROM ratings WHERE seq = (SELECT max(seq) FROM ratings)")
    out = tmp_path / "r"
    code, stdout, err = analyze(capsys, "report", "--manifest", path, "--sessions", s,
                                "--model", "mos", "--outliers", "none", "--bootstrap", "20",
                                "--splits", "20", "--out", out)
    assert code == 0, err
    methods = " ".join((out / "methods.txt").read_text().split())
    assert ("Not analysed: 1 rater whose session file was altered after it was recorded "
            "(P4), leaving less than 50% of their trials with intact records.") in methods
    assert ("1 rater whose session file was altered after it was recorded was kept with the "
            "ratings recorded before the change (P5: the session record counts 6 rating(s) "
            "ending in a different hash than the 5 row(s) present).") in methods
    assert "answered less than" not in methods and "incomplete session" not in methods
    exclusions = pd.read_csv(out / "tables" / "exclusions.csv")
    p4 = exclusions[exclusions["who"] == "P4"]
    assert list(p4["kind"]) == ["altered session"]
    assert "hash chain broken at trial" in p4["reason"].iloc[0]
    assert "1 of 6 planned trials" in p4["reason"].iloc[0]
    html = (out / "report.html").read_text()
    assert "2 session file(s) altered outside the app" in html
    assert "Partial session(s) kept" not in html
    assert "session files altered outside the app" in stdout and "P5 (kept)" in stdout


def test_the_report_lists_the_session_files_and_names_those_the_pull_had(tmp_path, capsys):
    """A sessions folder was recorded by its path alone, and a file missing from a copy of a
    pull went unnoticed while every number shifted."""
    import hashlib
    import json

    path = _study(tmp_path)
    loaded = load_manifest(path)
    s = tmp_path / "pulled"
    s.mkdir()
    files = {p: player_session(s, loaded, p, seed=k + 1)
             for k, p in enumerate(("P1", "P2", "P3", "P4"))}
    listing = {"study_id": "altered", "withdrawn": [{"participant": "P9"}],
               "participants": [{"participant": p, "session": {"n_ratings": 6}}
                                for p in ("P1", "P2", "P3", "P4", "P5", "P9")]
               + [{"participant": "P6", "session": None}]}
    (s / "server_listing.json").write_text(json.dumps(listing))
    out = tmp_path / "r"
    code, _, err = analyze(capsys, "report", "--manifest", path, "--sessions", s, "--model",
                           "mos", "--outliers", "none", "--bootstrap", "20", "--splits", "20",
                           "--out", out)
    assert code == 0, err
    # P5 had ratings and no file here; P6 never started, P9 withdrew: not missing
    assert ("the pull listed 1 participant(s) with ratings whose session file is not in "
            f"{s}: P5;") in err
    problems = pd.read_csv(out / "tables" / "problems.csv")
    assert problems["message"].str.contains("P5; they are not in any number here").any()
    inputs = json.loads((out / "summary.json").read_text())["inputs"]["sessions"]
    listed = {f["name"]: f["sha256"] for f in inputs[0]["files"]}
    assert set(listed) == {f"{p}.sqlite" for p in files} | {"server_listing.json"}
    for p, f in files.items():
        assert listed[f"{p}.sqlite"] == hashlib.sha256(f.read_bytes()).hexdigest()


def test_a_manifest_that_only_changed_its_line_endings_is_named_so(tmp_path, capsys):
    """git autocrlf or an upload converted the manifest to CRLF: every session was refused as
    'the study changed after this session', which sends the reader looking for a change."""
    path = _study(tmp_path)
    loaded = load_manifest(path)
    s = tmp_path / "s"
    s.mkdir()
    for k, p in enumerate(("P1", "P2", "P3")):
        player_session(s, loaded, p, seed=k + 1)
    crlf = tmp_path / "crlf" / "manifest.json"
    crlf.parent.mkdir()
    crlf.write_bytes(path.read_bytes().replace(b"\n", b"\r\n"))
    code, _, err = analyze(capsys, "dmos", "--manifest", crlf, "--sessions", s, "--out",
                           tmp_path / "d.csv")
    assert code == 2
    assert "before its line endings were changed" in err and "study changed" not in err


def test_simulated_raters_spend_no_time_in_the_study():
    """'Time in the study: median 0.0 min (0.0-0.0)' was reported for simulated sessions."""
    from analysis.report import _minutes

    quality = pd.DataFrame({"timing_mode": ["simulated", "simulated", "vsync"],
                            "minutes": [0.0, 0.0, 12.5]}, index=["S1", "S2", "P1"])
    assert _minutes(quality, ["S1", "S2"]) is None
    assert _minutes(quality, ["S1", "S2", "P1"]) == {"n": 1, "median": 12.5, "min": 12.5,
                                                     "max": 12.5}
