"""Session store: round trip, ordering rules, finished sessions, tampering, SIGKILL + resume."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from support.tamper import edit_database

from session_store import (
    RATINGS_COLUMNS,
    SCHEMA_VERSION,
    PlannedTrial,
    SessionStore,
    TrialResult,
    read_info,
    read_ratings,
    verify_session,
)
from session_store.errors import StudyError

REPO = Path(__file__).resolve().parents[2]


def make_plan(n: int = 4) -> list[PlannedTrial]:
    stims = ["SRC01_HRC01", "SRC01", "SRC02_HRC01", "SRC02"]
    return [
        PlannedTrial(i, stims[i % 4], "SRC01" if i % 4 < 2 else "SRC02", i // 4 + 1,
                     stims[i % 4] in ("SRC01", "SRC02"))
        for i in range(n)
    ]


def result(rating: float, **kw) -> TrialResult:
    base = dict(rating=rating, rt_ms=4000.0 + rating, n_toggles=2, ms_on_reference=1500.0,
                ms_on_test=2500.5, presented_at="2026-01-01T10:00:00.000Z",
                slider_first_move_ms=3000.0, frames_presented=240, dropped_frames=0,
                max_flip_interval_ms=16.9, switch_latencies_ms=[500.1, 516.7])
    base.update(kw)
    return TrialResult(**base)


def new_store(tmp_path: Path, n: int = 4) -> SessionStore:
    return SessionStore.create(
        tmp_path / "P01.sqlite", participant="P01", study_id="study-x",
        manifest_sha256="ab" * 32, seed=7, app_version="0.1.0", plan=make_plan(n),
    )


def test_round_trip_rows_have_contract_columns(tmp_path):
    with new_store(tmp_path) as store:
        assert store.next_trial().index == 0
        for i, value in enumerate([10.0, 99.5, 33.25, 0.0]):
            assert store.next_trial().index == i
            store.record(i, result(value))
        assert store.next_trial() is None
        assert store.progress() == (4, 4)
        store.finish()
    rows, problems = read_ratings(tmp_path / "P01.sqlite")
    assert problems == []
    assert [tuple(r) for r in rows] == [RATINGS_COLUMNS] * 4
    assert [r["rating"] for r in rows] == [10.0, 99.5, 33.25, 0.0]
    assert [r["trial"] for r in rows] == [0, 1, 2, 3]
    assert [r["stimulus"] for r in rows] == ["SRC01_HRC01", "SRC01", "SRC02_HRC01", "SRC02"]
    assert [r["is_hidden_reference"] for r in rows] == [False, True, False, True]
    assert rows[0]["participant"] == "P01" and rows[0]["study"] == "study-x"
    assert rows[1]["rt_ms"] == 4099.5 and rows[0]["ms_on_test"] == 2500.5
    report = verify_session(tmp_path / "P01.sqlite")
    assert (report.intact, report.complete, report.exit_code) == (True, True, 0)
    # WAL + synchronous FULL, as the contract requires.
    con = sqlite3.connect(tmp_path / "P01.sqlite")
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    con.close()


def test_order_and_duplicates_refused(tmp_path):
    with new_store(tmp_path) as store:
        with pytest.raises(StudyError, match="not the next unanswered"):
            store.record(1, result(50))
        store.record(0, result(50))
        with pytest.raises(StudyError, match="not the next unanswered"):
            store.record(0, result(51))
    rows, _ = read_ratings(tmp_path / "P01.sqlite")
    assert len(rows) == 1


def test_finished_session_refuses_ratings(tmp_path):
    with new_store(tmp_path) as store:
        store.record(0, result(50))
        with pytest.raises(StudyError, match="unanswered"):
            store.finish()
        store.finish(allow_incomplete=True)
        with pytest.raises(StudyError, match="finished"):
            store.record(1, result(50))
    with SessionStore.open(tmp_path / "P01.sqlite") as store, pytest.raises(StudyError):
        store.record(1, result(50))
    report = verify_session(tmp_path / "P01.sqlite")
    assert (report.intact, report.complete, report.exit_code) == (True, False, 1)


def test_existing_file_not_overwritten(tmp_path):
    new_store(tmp_path).close()
    with pytest.raises(StudyError, match="already exists"):
        new_store(tmp_path)


def _filled(tmp_path: Path) -> Path:
    with new_store(tmp_path) as store:
        for i in range(4):
            store.record(i, result(10.0 * (i + 1)))
        store.finish()
    return tmp_path / "P01.sqlite"


def test_edited_rating_breaks_chain_from_that_row(tmp_path):
    path = _filled(tmp_path)
    edit_database(path, "UPDATE ratings SET rating = 95 WHERE trial = 2")
    rows, problems = read_ratings(path)
    assert [r["rating"] for r in rows] == [10.0, 20.0]
    assert len(problems) == 1 and problems[0].row == 2 and "hash chain" in problems[0].message
    report = verify_session(path)
    assert not report.intact and report.exit_code == 2


def test_edited_participant_and_removed_tail_detected(tmp_path):
    path = _filled(tmp_path)
    edit_database(path, "DELETE FROM ratings WHERE seq = 4")
    rows, problems = read_ratings(path)
    assert len(rows) == 3 and len(problems) == 1 and "removed" in problems[0].message
    edit_database(path, "UPDATE session SET participant = 'P99'")
    rows, problems = read_ratings(path)
    assert rows == [] and problems[0].row == 0


def test_schema_version_and_foreign_files(tmp_path):
    path = _filled(tmp_path)
    assert read_info(path).participant == "P01"
    edit_database(path, "UPDATE meta SET value = 'cgvq-session/2' WHERE key = 'schema'")
    with pytest.raises(StudyError, match="not supported"):
        read_ratings(path)
    other = tmp_path / "other.sqlite"
    sqlite3.connect(other).execute("CREATE TABLE t (x)").connection.commit()
    with pytest.raises(StudyError, match="not a cgvq-study session file"):
        read_ratings(other)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"hello, not a database" * 100)
    with pytest.raises(StudyError):
        verify_session(junk)
    assert SCHEMA_VERSION == "cgvq-session/1"


def test_requeue_appends_same_stimulus_at_end(tmp_path):
    with new_store(tmp_path) as store:
        store.record(0, result(40))
        new = store.requeue(1, result(41, dropped_frames=30), "30 dropped frames")
        assert (new.index, new.stimulus, new.repetition, new.requeue_of) == (4, "SRC01", 1, 1)
        assert [store.next_trial().index] == [2]
        assert store.progress() == (1, 4)
        store.record(2, result(42))
        store.record(3, result(43))
        assert store.next_trial().index == 4
        store.record(4, result(44))
        assert store.next_trial() is None
        store.finish()
        outcomes = [(p["trial"], p["outcome"]) for p in store.presentations()]
    assert outcomes == [(0, "rated"), (1, "requeued"), (2, "rated"), (3, "rated"), (4, "rated")]
    rows, problems = read_ratings(tmp_path / "P01.sqlite")
    assert problems == [] and [r["rating"] for r in rows] == [40, 42, 43, 44]
    assert sorted(r["stimulus"] for r in rows) == sorted(p.stimulus for p in make_plan())
    assert verify_session(tmp_path / "P01.sqlite").exit_code == 0


CHILD = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from session_store import PlannedTrial, SessionStore, TrialResult
    path = Path(sys.argv[1])
    plan = [PlannedTrial(i, f"S{i % 5}", "R", i // 5 + 1, False) for i in range(40)]
    if path.exists():
        store = SessionStore.open(path)
    else:
        store = SessionStore.create(path, participant="K", study_id="s", manifest_sha256=None,
                                    seed=1, app_version="t", plan=plan)
    while (t := store.next_trial()) is not None:
        r = TrialResult(rating=float(t.index), rt_ms=1.0, n_toggles=0, ms_on_reference=0.0,
                        ms_on_test=1.0, presented_at="2026-01-01T00:00:00Z")
        store.record(t.index, r)
        print(t.index, flush=True)
        time.sleep(float(sys.argv[2]))
    store.finish()
    store.close()
    print("done", flush=True)
    """
)


def test_sigkill_mid_session_then_resume_without_duplicates(tmp_path):
    path = tmp_path / "K.sqlite"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(path), "0.02"],
                            stdout=subprocess.PIPE, text=True, env=env)
    acknowledged = []
    deadline = time.monotonic() + 60
    while len(acknowledged) < 12 and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        acknowledged.append(int(line))
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    assert acknowledged == list(range(12))
    rows, problems = read_ratings(path)
    assert problems == []
    # Every acknowledged (committed) rating survived; at most the one in flight is extra.
    assert [r["trial"] for r in rows][:12] == list(range(12))
    assert len(rows) in (12, 13)
    # Resume in a fresh process: it starts exactly at the first unanswered trial.
    out = subprocess.run([sys.executable, "-c", CHILD, str(path), "0"], capture_output=True,
                         text=True, env=env, timeout=120, check=True).stdout.split()
    assert out[0] == str(len(rows)) and out[-1] == "done"
    rows, problems = read_ratings(path)
    assert problems == []
    assert [r["trial"] for r in rows] == list(range(40))
    assert [r["rating"] for r in rows] == [float(i) for i in range(40)]
    report = verify_session(path)
    assert report.exit_code == 0 and report.n_ratings == 40
