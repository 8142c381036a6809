"""Experimenter tools: check, export, verify; pre-flight failure messages."""

from __future__ import annotations

import csv
import sqlite3
import zipfile

import pytest

from stimuli_manifests import DisplayRequirements
from study_app.cli import main
from study_app.errors import StudyError
from study_app.export import export_session, verify_file
from study_app.preflight import (
    check_checksums,
    check_decode_speed,
    check_memory,
    check_pixel_mapping,
    check_refresh,
    check_screen,
    raise_for_failures,
)
from study_app.schedule import make_schedule
from study_app.session import RATINGS_COLUMNS, SessionStore, TrialResult
from study_app.study import check_study, load_study

REQ = DisplayRequirements()  # 1920x1080, 59 Hz


def test_preflight_messages_say_what_to_change():
    c = check_screen(1366, 768, REQ)
    assert not c.ok and "1366x768" in c.message and "1920x1080" in c.message
    assert "scaling to 100%" in c.message
    assert check_screen(2560, 1440, REQ).ok

    good = [1 / 60] * 60
    c = check_refresh(good, REQ, vsync=True)
    assert c.ok and c.value["hz"] == pytest.approx(60.0, abs=0.01)
    c = check_refresh([1 / 30] * 60, REQ, vsync=True)
    assert not c.ok and "30.0 Hz" in c.message and "59 Hz" in c.message
    jittery = [1 / 60] * 45 + [1 / 40] * 15  # median rate is fine, the spread is not
    c = check_refresh(jittery, REQ, vsync=True)
    assert not c.ok and "unstable" in c.message
    c = check_refresh([], REQ, vsync=False, paced_hz=60)
    assert c.ok and c.warning and c.value == {"vsync": False, "hz": 60.0}
    assert not check_refresh([], REQ, vsync=False, paced_hz=50).ok

    c = check_pixel_mapping((1920, 1080), (3840, 2160), (1024, 1024))
    assert not c.ok and "scaling to 100%" in c.message
    c = check_pixel_mapping((1280, 720), (1280, 720), (1024, 1024))
    assert not c.ok and "do not fit" in c.message
    assert check_pixel_mapping((1920, 1080), (1920, 1080), (1024, 1024)).ok

    c = check_memory(4 * 1024**3, 1 * 1024**3)
    assert not c.ok and "1.0 GiB" in c.message and "4.0 GiB" in c.message
    assert check_memory(1, None).ok
    c = check_decode_speed(25.0)
    assert not c.ok and "25.0 s" in c.message and "faster computer" in c.message
    with pytest.raises(StudyError, match="screen_size: the screen is 1366x768"):
        raise_for_failures([check_screen(1366, 768, REQ), check_decode_speed(1.0)])


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
    plan = make_schedule(study.schedule_items(), 1, 3)
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
    with zipfile.ZipFile(out) as zf:
        assert set(zf.namelist()) == {"session.sqlite", "ratings.csv", "SHA256SUMS"}
    with open(csv_out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == RATINGS_COLUMNS
    assert [float(r["rating"]) for r in rows] == [10.0, 20.0, 30.0]
    assert main(["verify", str(out)]) == 0
    assert main(["verify", str(path)]) == 0
    # A zip whose session member was altered fails the checksum.
    bad = tmp_path / "bad.zip"
    with zipfile.ZipFile(out) as zin, zipfile.ZipFile(bad, "w") as zout:
        for name in zin.namelist():
            data = zin.read(name)
            if name == "session.sqlite":
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
    con = sqlite3.connect(path)
    con.execute("UPDATE ratings SET rt_ms = 5 WHERE seq = 1")
    con.commit()
    con.close()
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
