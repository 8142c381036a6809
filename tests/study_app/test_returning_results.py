"""Returning results safely: the .sqlite alone holds every committed rating, WAL side files
are flagged, exports have unique names, verify takes many files, reads see one snapshot."""

from __future__ import annotations

import shutil
import signal
import sqlite3
import subprocess
import sys
import threading
import zipfile
from pathlib import Path

import pytest

from cgvq_cli.study_cli import main
from session_store import (
    PlannedTrial,
    SessionStore,
    TrialResult,
    read_session,
    verify_session,
)
from session_store.errors import StudyError
from study_app.export import export_session, verify_many

REPO = Path(__file__).resolve().parents[2]


def _plan(n: int) -> list[PlannedTrial]:
    return [PlannedTrial(i, f"S{i % 3}", "R", i // 3 + 1, False) for i in range(n)]


def _result(v: float) -> TrialResult:
    return TrialResult(rating=v, rt_ms=1000.0, n_toggles=1, ms_on_reference=1.0,
                       ms_on_test=2.0, presented_at="2026-01-01T00:00:00.000Z")


def _store(path: Path, participant: str = "P01", n: int = 6) -> SessionStore:
    return SessionStore.create(path, participant=participant, study_id="s", manifest_sha256=None,
                               seed=1, app_version="t", plan=_plan(n))


KILLED_WRITER = """
import os, signal, sys
from session_store import PlannedTrial, SessionStore, TrialResult
path, n, skip_checkpoint = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1"
store = SessionStore.open(path)
if skip_checkpoint:  # what the app did before every write was checkpointed
    store._checkpoint = lambda: None
    store._con.execute("PRAGMA wal_autocheckpoint=0")
for i in range(n):
    store.record(i, TrialResult(rating=10.0 * (i + 1), rt_ms=1.0, n_toggles=0,
                                ms_on_reference=0.0, ms_on_test=1.0,
                                presented_at="2026-01-01T00:00:00.000Z"))
os.kill(os.getpid(), signal.SIGKILL)
"""


def _killed_writer(path: Path, n: int, *, skip_checkpoint: bool) -> None:
    proc = subprocess.run([sys.executable, "-c", KILLED_WRITER, str(path), str(n),
                           "1" if skip_checkpoint else "0"],
                          env={"PYTHONPATH": str(REPO)}, capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr


def test_sigkill_after_submit_then_only_the_sqlite_loses_no_rating(tmp_path):
    path = tmp_path / "P01.sqlite"
    _store(path).close()
    _killed_writer(path, 3, skip_checkpoint=False)
    sent = tmp_path / "sent"
    sent.mkdir()
    shutil.copy(path, sent / "P01.sqlite")  # the participant sends the bare file
    rows = read_session(sent / "P01.sqlite").ratings
    assert [r["rating"] for r in rows] == [10.0, 20.0, 30.0]
    report = verify_session(sent / "P01.sqlite")
    assert report.intact and report.n_ratings == 3 and report.warnings == []


def test_verify_warns_when_the_wal_holds_ratings_the_file_lacks(tmp_path, capsys):
    path = tmp_path / "P01.sqlite"
    _store(path).close()
    _killed_writer(path, 2, skip_checkpoint=True)
    assert Path(f"{path}-wal").stat().st_size > 0
    report = verify_session(path)
    assert report.n_ratings == 2  # read together with its WAL: nothing lost here...
    assert len(report.warnings) == 1 and "2 committed rating(s)" in report.warnings[0]
    assert main(["verify", str(path)]) == 1
    assert "export" in capsys.readouterr().out
    # ...but the bare file alone lacks them, which is what the warning is about
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(path, bare / "P01.sqlite")
    assert read_session(bare / "P01.sqlite").ratings == []
    # the export takes the WAL's content along
    zpath = export_session(path, tmp_path / "out")
    assert verify_many([zpath])[0].n_ratings == 2


def test_exports_of_many_participants_unzip_into_one_folder(tmp_path, monkeypatch):
    paths = []
    for pid in ("P01", "P02"):
        path = tmp_path / "sessions" / f"{pid}.sqlite"
        with _store(path, pid) as store:
            store.record(0, _result(50.0))
        paths.append(path)
    returns = tmp_path / "returns"
    returns.mkdir()
    monkeypatch.chdir(returns)  # the default: the current folder, as the README says
    zips = [export_session(p) for p in paths]
    assert [z.parent for z in zips] == [returns, returns] and len(set(zips)) == 2
    unpacked = tmp_path / "unpacked"
    for z in zips:
        with zipfile.ZipFile(z) as zf:
            zf.extractall(unpacked)
    sqlites = sorted(unpacked.glob("*.sqlite"))
    assert len(sqlites) == 2
    assert {read_session(p).info.participant for p in sqlites} == {"P01", "P02"}


def test_verify_takes_files_folders_and_zips_at_once(tmp_path, capsys):
    done = tmp_path / "in" / "P01.sqlite"
    with _store(done, "P01", n=2) as store:
        store.record(0, _result(1.0))
        store.record(1, _result(2.0))
        store.finish()
    with _store(tmp_path / "in" / "P02.sqlite", "P02") as store:
        store.record(0, _result(1.0))
    z = export_session(done, tmp_path / "zips")
    broken = tmp_path / "broken.sqlite"
    broken.write_bytes(b"garbage")
    code = main(["verify", str(tmp_path / "in"), str(z), str(broken)])
    out = capsys.readouterr().out
    assert code == 2
    assert "P01.sqlite: intact and complete" in out
    assert "P02.sqlite: intact but INCOMPLETE" in out
    assert f"{z}:P01_" in out and "broken.sqlite: DAMAGED" in out
    assert "4 session files: 2 complete, 1 incomplete, 1 damaged" in out
    assert main(["verify", str(tmp_path / "in" / "P01.sqlite"), str(z)]) == 0
    capsys.readouterr()


def test_hostile_zip_members_stay_in_their_folder(tmp_path):
    path = tmp_path / "P01.sqlite"
    _store(path).close()
    evil = tmp_path / "evil.zip"
    with zipfile.ZipFile(evil, "w") as zf:
        zf.write(path, "../../escaped.sqlite")
    reports = verify_many([evil])
    assert len(reports) == 1 and reports[0].intact
    assert "no SHA256SUMS" in reports[0].warnings[0]
    assert not (tmp_path.parent / "escaped.sqlite").exists()


def test_export_refuses_files_edited_into_bad_ids_or_bad_json(tmp_path, capsys):
    path = tmp_path / "P01.sqlite"
    _store(path).close()
    con = sqlite3.connect(path)
    con.execute("UPDATE session SET participant='../../x'")
    con.commit()
    con.close()
    assert main(["export", str(path), "--out", str(tmp_path / "z")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'../../x' is not valid" in err
    assert not (tmp_path.parent / "x").exists() and not list(tmp_path.glob("*.zip"))
    path2 = tmp_path / "P02.sqlite"
    _store(path2, "P02").close()
    con = sqlite3.connect(path2)
    con.execute("UPDATE session SET settings='{not json'")
    con.commit()
    con.close()
    assert main(["export", str(path2)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "settings is not valid JSON" in err
    assert main(["verify", str(path2)]) == 2
    capsys.readouterr()


@pytest.mark.parametrize("bad", ["x" * 300, "../x", ".hidden", "a/b", "", "P 01"])
def test_invalid_participant_ids_create_nothing(tmp_path, bad):
    with pytest.raises(StudyError, match="participant id"):
        _store(tmp_path / "s.sqlite", bad)
    assert list(tmp_path.iterdir()) == []


def test_sessions_folder_that_is_a_file_is_a_clear_error(tmp_path):
    (tmp_path / "sessions").write_text("")
    with pytest.raises(StudyError, match="is a file"):
        _store(tmp_path / "sessions" / "P01.sqlite")


def test_withdrawn_session_is_closed_and_reported(tmp_path, capsys):
    path = tmp_path / "P01.sqlite"
    with _store(path) as store:
        store.record(0, _result(5.0))
        store.withdraw()
        assert store.info.withdrawn and store.is_finished
        with pytest.raises(StudyError, match="finished"):
            store.record(1, _result(5.0))
    report = verify_session(path)
    assert report.intact and not report.complete and report.state == "withdrawn"
    assert main(["verify", str(path)]) == 1
    assert "withdrawn by the participant" in capsys.readouterr().out


def test_reading_while_the_app_writes_never_reports_tampering(tmp_path):
    """Header, plan and ratings come from one snapshot (before: 3.8 % of such reads said
    'rating rows were removed or added')."""
    path = tmp_path / "P01.sqlite"
    n = 150
    _store(path, n=n).close()
    stop = threading.Event()
    seen: list[int] = []
    problems: list[str] = []

    def reader() -> None:
        while not stop.is_set():
            rec = read_session(path)
            seen.append(len(rec.ratings))
            problems.extend(str(p) for p in rec.problems)

    thread = threading.Thread(target=reader)
    thread.start()
    try:
        with SessionStore.open(path) as store:
            for i in range(n):
                store.record(i, _result(float(i)))
    finally:
        stop.set()
        thread.join(timeout=60)
    assert problems == []
    assert len(set(seen)) > 10  # the reads really overlapped the writes
    assert seen == sorted(seen)


