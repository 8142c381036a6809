"""Experimenter tools: check, export, verify (pre-flight messages: test_preflight.py)."""

from __future__ import annotations

import csv
import zipfile

import pytest
from support.tamper import edit_database

from cgvq_cli.study_cli import main
from session_store import RATINGS_COLUMNS, SessionStore, TrialResult
from session_store.errors import StudyError
from session_store.schedule import make_schedule, schedule_items
from session_store.study_folder import load_study
from study_app.export import export_name, export_session, verify_file
from study_app.preflight import check_checksums
from study_app.study_check import check_study


def test_check_study_ok_and_broken(tiny_study, capsys):
    assert main(["check", str(tiny_study)]) == 0
    assert "3 stimuli x 1 repetitions = 3 trials" in capsys.readouterr().out
    study = load_study(tiny_study)
    assert check_study(study).ok
    assert check_checksums(study).ok
    # A modified stimulus: checksum error in check and in the pre-flight.
    video = tiny_study / "videos" / "ref0_noise1.mkv"
    video.write_bytes(video.read_bytes() + b"x")
    result = check_study(load_study(tiny_study))
    assert not result.ok and any("checksum" in e for e in result.errors)
    c = check_checksums(load_study(tiny_study))
    assert not c.ok and "download or unpack the study folder again" in c.message
    assert main(["check", str(tiny_study)]) == 2


def test_check_study_finds_mismatched_pair(tmp_path, study_factory):
    folder = study_factory(tmp_path / "s", min_display=(32, 32))
    result = check_study(load_study(folder))
    assert any("does not fit the minimum display 32x32" in e for e in result.errors)
    assert main(["check", str(tmp_path / "nowhere")]) == 2


def _session(study_dir, n_answer):
    study = load_study(study_dir)
    plan = make_schedule(schedule_items(study.manifest), 1, 3)
    path = study.session_path("P07")
    with SessionStore.create(path, participant="P07", study_id="tiny-study",
                             manifest_sha256=study.loaded.sha256, seed=3, app_version="t",
                             plan=plan) as store:
        for trial in plan[:n_answer]:
            store.record(trial.index, TrialResult(
                rating=10.0 * (trial.index + 1), rt_ms=1000.0, n_toggles=1,
                ms_on_reference=1.0, ms_on_test=2.0, presented_at="2026-01-01T00:00:00Z"))
        if n_answer == len(plan):
            store.finish()
    return path


def test_export_zip_and_verify(tiny_study, tmp_path, capsys):
    path = _session(tiny_study, 3)
    out = tmp_path / "back.zip"
    csv_out = tmp_path / "ratings.csv"
    assert main(["export", str(path), "--out", str(out), "--csv", str(csv_out)]) == 0
    stem = export_name(path)
    assert stem.startswith("P07_")
    with zipfile.ZipFile(out) as zf:
        assert set(zf.namelist()) == {f"{stem}.sqlite", f"{stem}_ratings.csv", "SHA256SUMS"}
    with open(csv_out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == (*RATINGS_COLUMNS, "format")
    assert {r["format"] for r in rows} == {"cgvq-ratings/1.1"}
    assert [float(r["rating"]) for r in rows] == [10.0, 20.0, 30.0]
    assert main(["verify", str(out)]) == 0
    assert main(["verify", str(path)]) == 0
    # A zip whose session member was altered fails the checksum.
    bad = tmp_path / "bad.zip"
    with zipfile.ZipFile(out) as zin, zipfile.ZipFile(bad, "w") as zout:
        for name in zin.namelist():
            data = zin.read(name)
            if name.endswith(".sqlite"):
                data = data[:-1] + bytes([data[-1] ^ 1])
            zout.writestr(name, data)
    report = verify_file(bad)
    assert not report.intact and "checksum mismatch" in report.problems[0].message
    assert main(["verify", str(bad)]) == 2
    capsys.readouterr()


def test_verify_exit_codes(tiny_study, tmp_path):
    path = _session(tiny_study, 2)
    assert main(["verify", str(path)]) == 1
    assert verify_file(export_session(path, tmp_path / "x.zip")).exit_code == 1
    edit_database(path, "UPDATE ratings SET rt_ms = 5 WHERE seq = 1")
    assert main(["verify", str(path)]) == 2
    junk = tmp_path / "junk.sqlite"
    junk.write_text("not a database")
    assert main(["verify", str(junk)]) == 2


def test_prefetch_decodes_pair_and_refuses_mismatch(tiny_study, tmp_path, study_factory):
    from stimuli_manifests import read_video
    from study_app.decode import Prefetcher, decode_pair

    study = load_study(tiny_study)
    test, ref = study.loaded.stimulus_path("SRC01_HRC01"), study.loaded.reference_path("SRC01")
    pf = Prefetcher()
    try:
        assert pf.take(5) is None
        pf.start(5, "SRC01_HRC01", test, ref)
        pair = pf.take(5)
    finally:
        pf.close()
    assert pair.fps == 30 and pair.test.shape == (30, 64, 64, 3)
    assert (pair.test == read_video(test)).all() and (pair.reference == read_video(ref)).all()
    other = study_factory(tmp_path / "big", size=32, briefing=False, consent=False)
    with pytest.raises(StudyError, match="differ"):
        decode_pair("x", test, load_study(other).loaded.reference_path("SRC01"))


def test_run_refuses_another_seed_for_a_resumed_session(tiny_study, capsys):
    """The plan of a started session comes from its file; a --seed that differs from the
    stored one would be ignored, so it is refused before any window opens."""
    session = _session(tiny_study, 1)  # started with seed 3, one trial answered
    before = session.read_bytes()
    code = main(["run", str(tiny_study), "--participant", "P07", "--seed", "4",
                 "--pilot-no-vsync"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert "--seed 4: this session was started with seed 3" in err
    assert session.read_bytes() == before


def test_check_names_session_files_that_would_travel_and_groups_shared_warnings(
        tiny_study, capsys):
    from cgvq_cli.study_commands.check import grouped_warnings

    assert main(["check", str(tiny_study)]) == 0
    assert "session file" not in capsys.readouterr().out
    (tiny_study / "sessions").mkdir()
    _session(tiny_study, 3)  # P07, as a pilot run without --sessions-dir leaves it
    assert main(["check", str(tiny_study)]) == 0  # a warning, not an error
    out = capsys.readouterr().out
    assert "warning: sessions/ holds 1 session file(s) (P07): sent with the study folder, " \
           "they reach every participant" in out
    ids = {"a", "b", "c", "d"}
    assert grouped_warnings(["a: lossy", "b: lossy", "c: lossy", "d: short", "x: other",
                             "several frame rates"], ids) == [
        "3 videos (a, b, c): lossy", "d: short", "x: other", "several frame rates"]
    assert grouped_warnings([f"{s}: lossy" for s in "abcd"], ids) == [
        "4 videos (a, b, c and 1 more): lossy"]


def test_verify_names_a_pilot(tiny_study, capsys):
    from support.sessions import player_session

    from stimuli_manifests import load_manifest

    folder = tiny_study.parent / "pilots"
    folder.mkdir()
    loaded = load_manifest(tiny_study / "manifest.json")
    path = player_session(folder, loaded, "PILOT01", timing="paced-pilot")
    assert main(["verify", str(path)]) == 0
    assert "a pilot: paced on the clock without vsync (timing mode paced-pilot)" in \
        capsys.readouterr().out
    participant = player_session(folder, loaded, "P01")
    assert main(["verify", str(participant)]) == 0
    assert "a pilot" not in capsys.readouterr().out


def test_check_names_a_missing_consent_text_and_what_the_panel_collects(tmp_path, capsys):
    from support.studies import make_study

    with_consent = make_study(tmp_path / "a")
    assert not any("consent" in w for w in check_study(load_study(with_consent)).warnings)
    folder = make_study(tmp_path / "b", consent=False)
    (said,) = [w for w in check_study(load_study(folder)).warnings if "consent" in w]
    assert said.startswith("no consent text (consent.md beside the manifest)")
    assert "health data" not in said
    assert main(["panel", str(folder), "--add-templates"]) == 0  # vision checks included
    capsys.readouterr()
    assert main(["check", str(folder)]) == 0  # a warning, not an error
    out = capsys.readouterr().out
    assert "warning: no consent text" in out and "vision checks collect health data" in out


def test_a_text_edited_after_its_checksum_gets_the_way_out(tmp_path):
    """After a pilot the briefing is edited; check said only "checksum mismatch"."""
    from support.studies import make_study

    folder = make_study(tmp_path / "s")
    assert check_study(load_study(folder)).ok
    (folder / "briefing.md").write_text((folder / "briefing.md").read_text() + "\nOne more.\n")
    result = check_study(load_study(folder))
    (said,) = [e for e in result.errors if "briefing.md" in e]
    assert said.startswith("checksum mismatch: briefing.md")
    assert f"'python -m stimuli_manifests hash {folder / 'manifest.json'}' and pilot again" \
        in said
    video = folder / "videos" / "ref0_noise1.mkv"
    video.write_bytes(video.read_bytes() + b"x")
    (other,) = [e for e in check_study(load_study(folder)).errors if "ref0_noise1" in e]
    assert "pilot again" not in other  # a video changed is no edit to record
