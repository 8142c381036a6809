"""A full disk at the checkpoint after a rating (finding 1 of the session audit): the rating is
committed to the WAL, but the main file may now be readable only together with its -wal. The
writer must say so (a StudyError naming both files), never report the rating as saved, never
let a raw sqlite3 error through, and close() must not hide it; readers and export must still
get every committed rating from the pair."""

from __future__ import annotations

import shutil
import signal
import sqlite3
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from support.sessions import bare_session, plain_result

from session_store import SessionStore, read_session, verify_session
from session_store.errors import StudyError
from study_app.export import export_session

REPO = Path(__file__).resolve().parents[2]


class _FailingDisk:
    """The writer's connection, failing the statements that start with ``fail_on`` as SQLite
    does on a full disk (SQLITE_FULL) or an I/O error, once ``failing`` is set."""

    def __init__(self, con: sqlite3.Connection, fail_on: str, code: int = sqlite3.SQLITE_FULL):
        self._con, self.fail_on, self.code, self.failing = con, fail_on, code, False

    def execute(self, sql: str, *args: object) -> sqlite3.Cursor:
        if self.failing and sql.startswith(self.fail_on):
            exc = sqlite3.OperationalError("database or disk is full"
                                           if self.code == sqlite3.SQLITE_FULL
                                           else "disk I/O error")
            exc.sqlite_errorcode = self.code
            raise exc
        return self._con.execute(sql, *args)

    def __getattr__(self, name: str) -> object:
        return getattr(self._con, name)


def _failing(store: SessionStore, fail_on: str, code: int = sqlite3.SQLITE_FULL
             ) -> _FailingDisk:
    disk = _FailingDisk(store._con, fail_on, code)
    store._con = disk  # type: ignore[assignment]
    return disk


def test_a_failed_checkpoint_is_not_a_saved_rating(tmp_path):
    path = tmp_path / "P07.sqlite"
    store = bare_session(path, participant="P07")
    store.record(0, plain_result(10.0))
    disk = _failing(store, "PRAGMA wal_checkpoint")
    disk.failing = True
    with pytest.raises(StudyError) as caught:
        store.record(1, plain_result(20.0))
    message = str(caught.value)
    assert "\n" not in message and "the disk is full" in message
    assert "2 rating(s) so far (up to trial 2)" in message
    assert "P07.sqlite and P07.sqlite-wal" in message and "not send P07.sqlite alone" in message
    # the rating is committed (in the WAL): a reader of the pair sees both ratings
    assert [r["rating"] for r in read_session(path).ratings] == [10.0, 20.0]
    # (another connection stays open, so SQLite's own checkpoint at the last close, which
    # a really full disk would fail too, leaves the -wal as it is)
    held = sqlite3.connect(path)
    held.execute("SELECT count(*) FROM ratings").fetchone()
    with pytest.raises(StudyError, match="the disk is full"):  # close() does not hide it
        store.close()
    assert Path(f"{path}-wal").stat().st_size > 0
    # the .sqlite alone lacks the second rating; verify of the pair says to send both
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(path, alone / path.name)
    assert len(read_session(alone / path.name).ratings) == 1
    report = verify_session(path)
    assert report.n_ratings == 2 and any("-wal" in w for w in report.warnings)
    # export folds the WAL in: the zip's copy holds both ratings
    out = export_session(path, tmp_path / "out.zip")
    with zipfile.ZipFile(out) as zf:
        member = next(n for n in zf.namelist() if n.endswith(".sqlite"))
        zf.extract(member, tmp_path / "unzipped")
    assert len(read_session(tmp_path / "unzipped" / member).ratings) == 2
    held.close()
    # with space again, the next run merges the pair and continues at trial 3
    with SessionStore.open(path) as again:
        assert again.next_trial().index == 2
    shutil.copy(path, alone / path.name)
    assert len(read_session(alone / path.name).ratings) == 2


def test_a_failed_commit_says_the_rating_on_screen_was_not_saved(tmp_path):
    path = tmp_path / "P07.sqlite"
    store = bare_session(path, participant="P07")
    store.record(0, plain_result(10.0))
    disk = _failing(store, "COMMIT")
    disk.failing = True
    with pytest.raises(StudyError, match="rating on screen was not saved") as caught:
        store.record(1, plain_result(20.0))
    assert "1 rating(s) so far" in str(caught.value)
    assert not store._con.in_transaction
    disk.failing = False  # space freed: the same trial is recorded, once
    store.record(1, plain_result(20.0))
    store.close()
    assert [r["rating"] for r in read_session(path).ratings] == [10.0, 20.0]


def test_an_io_error_at_checkpoint_is_a_study_error_too(tmp_path):
    store = bare_session(tmp_path / "P07.sqlite", participant="P07")
    disk = _failing(store, "PRAGMA wal_checkpoint", sqlite3.SQLITE_IOERR_WRITE)
    disk.failing = True
    with pytest.raises(StudyError, match="the disk could not be written"):
        store.log_event("pause")
    disk.failing = False
    store.close()


def test_a_busy_reader_only_postpones_the_checkpoint(tmp_path):
    store = bare_session(tmp_path / "P07.sqlite", participant="P07")
    disk = _failing(store, "PRAGMA wal_checkpoint", sqlite3.SQLITE_BUSY)
    disk.failing = True
    store.record(0, plain_result(10.0))  # no error: the next checkpoint catches up
    disk.failing = False
    store.close()
    assert len(read_session(tmp_path / "P07.sqlite").ratings) == 1


FILE_SIZE_LIMIT = """
import resource, signal, sys
from pathlib import Path
from session_store.errors import StudyError
from support.sessions import bare_session, plain_result
path = Path(sys.argv[1])
store = bare_session(path, n=60)
store.record(0, plain_result(1.0))
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the main file cannot grow any more
resource.setrlimit(resource.RLIMIT_FSIZE, (path.stat().st_size, resource.RLIM_INFINITY))
acked = 1
try:
    for i in range(1, 60):
        store.record(i, plain_result(float(i)))
        acked += 1
except StudyError as exc:
    print("record:", exc)
try:
    store.close()
except StudyError as exc:
    print("close:", exc)
print("acked", acked)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_FSIZE on Linux")
def test_a_real_partial_checkpoint_keeps_every_rating_in_the_pair(tmp_path):
    """A real failed checkpoint (the file may not grow: SQLite has copied some pages into
    the main file and then fails), in a child process: every acknowledged rating is in the
    pair, the main file alone may be unreadable, and the message says to keep both."""
    path = tmp_path / "P01.sqlite"
    proc = subprocess.run([sys.executable, "-c", FILE_SIZE_LIMIT, str(path)], capture_output=True,
                          text=True, timeout=120,
                          env={"PYTHONPATH": f"{REPO}{':'}{REPO / 'tests'}"})
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    lines = dict(line.split(": ", 1) if ": " in line else ("acked", line.split()[1])
                 for line in proc.stdout.splitlines())
    acked = int(lines["acked"])
    assert "P01.sqlite and P01.sqlite-wal" in lines["record"]
    assert "P01.sqlite and P01.sqlite-wal" in lines["close"]
    ratings = read_session(path).ratings
    assert len(ratings) >= acked and verify_session(path).intact
    assert signal.SIGXFSZ  # (the child ignored it; a write past the limit fails instead)


def test_commits_reach_the_platter_on_macos_too(tmp_path):
    """fsync() on macOS stops at the drive's cache, so a power cut can lose ratings that
    synchronous=FULL reported as written; the writer asks SQLite for F_FULLFSYNC. SQLite keeps
    both settings on every platform, so they can be read back here."""
    store = bare_session(tmp_path / "P01.sqlite")
    try:
        con = store._con
        assert con.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
        assert con.execute("PRAGMA fullfsync").fetchone()[0] == 1
        assert con.execute("PRAGMA checkpoint_fullfsync").fetchone()[0] == 1
    finally:
        store.close()
