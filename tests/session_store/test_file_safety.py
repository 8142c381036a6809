"""The session file is safe to send back: the .sqlite alone holds every committed rating
(ratings left in a WAL side file are flagged), bad ids and folders create nothing, a withdrawal
closes the file, reads beside the writer see one snapshot, and a zip damaged in transit is
named as a damaged zip (never a traceback)."""

from __future__ import annotations

import hashlib
import random
import shutil
import signal
import struct
import subprocess
import sys
import threading
import zipfile
import zlib
from pathlib import Path

import pytest
from support.sessions import bare_session, plain_result

from cgvq_cli.study_cli import main
from session_store import SessionStore, read_session, session_sources, verify_session
from session_store.errors import StudyError
from study_app.export import export_session, verify_many

REPO = Path(__file__).resolve().parents[2]


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
    bare_session(path).close()
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
    bare_session(path).close()
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


@pytest.mark.parametrize("bad", ["x" * 300, "../x", ".hidden", "a/b", "", "P 01"])
def test_invalid_participant_ids_create_nothing(tmp_path, bad):
    with pytest.raises(StudyError, match="participant id"):
        bare_session(tmp_path / "s.sqlite", bad)
    assert list(tmp_path.iterdir()) == []


def test_sessions_folder_that_is_a_file_is_a_clear_error(tmp_path):
    (tmp_path / "sessions").write_text("")
    with pytest.raises(StudyError, match="is a file"):
        bare_session(tmp_path / "sessions" / "P01.sqlite")


def test_withdrawn_session_is_closed_and_reported(tmp_path, capsys):
    path = tmp_path / "P01.sqlite"
    with bare_session(path) as store:
        store.record(0, plain_result(5.0))
        store.withdraw()
        assert store.info.withdrawn and store.is_finished
        with pytest.raises(StudyError, match="finished"):
            store.record(1, plain_result(5.0))
    report = verify_session(path)
    assert report.intact and not report.complete and report.state == "withdrawn"
    assert main(["verify", str(path)]) == 1
    assert "withdrawn by the participant" in capsys.readouterr().out


def test_reading_while_the_app_writes_never_reports_tampering(tmp_path):
    """Header, plan and ratings come from one snapshot (before: 3.8 % of such reads said
    'rating rows were removed or added')."""
    path = tmp_path / "P01.sqlite"
    n = 150
    bare_session(path, n=n).close()
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
                store.record(i, plain_result(float(i)))
    finally:
        stop.set()
        thread.join(timeout=60)
    assert problems == []
    assert len(set(seen)) > 10  # the reads really overlapped the writes
    assert seen == sorted(seen)


def _listing(folder: Path) -> dict[str, str]:
    return {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in sorted(folder.iterdir())}


def test_reading_returned_sessions_leaves_their_folder_as_it_was(tmp_path, capsys):
    """Reading, verifying and exporting leave no empty -wal/-shm beside the files (before:
    every read left two) and change no byte of them."""
    returned = tmp_path / "returned"
    returned.mkdir()
    for who in ("P01", "P02"):
        with bare_session(returned / f"{who}.sqlite", participant=who, n=3) as store:
            for i in range(3):
                store.record(i, plain_result(10.0 * i))
            store.finish()
    before = _listing(returned)
    assert sorted(before) == ["P01.sqlite", "P02.sqlite"]
    for path in sorted(returned.iterdir()):
        assert len(read_session(path).ratings) == 3
        assert verify_session(path).problems == []
        export_session(path, tmp_path / "out")
    assert main(["verify", str(returned)]) == 0
    capsys.readouterr()
    assert _listing(returned) == before


def test_a_reader_beside_the_writer_leaves_its_side_files(tmp_path):
    """A read while the app has the file open keeps the app's -wal and -shm: the app goes on
    writing and every rating is in the file."""
    path = tmp_path / "P01.sqlite"
    bare_session(path, n=4).close()
    with SessionStore.open(path) as store:
        store.record(0, plain_result(1.0))
        assert read_session(path).ratings[0]["rating"] == 1.0
        assert Path(f"{path}-wal").exists() and Path(f"{path}-shm").exists()
        for i in range(1, 4):
            store.record(i, plain_result(float(i + 1)))
    assert [r["rating"] for r in read_session(path).ratings] == [1.0, 2.0, 3.0, 4.0]
    assert not Path(f"{path}-wal").exists()


# -- exported zips damaged in transit ------------------------------------------------------
def _overwrite_inside(archive: Path, member: str, where: float) -> None:
    """Overwrite 16 bytes of ``member``'s compressed data, ``where`` (0..1) into it."""
    with zipfile.ZipFile(archive) as zf:
        info = zf.getinfo(member)
    data = bytearray(archive.read_bytes())
    name_len, extra_len = struct.unpack("<HH", data[info.header_offset + 26:
                                                    info.header_offset + 30])
    at = info.header_offset + 30 + name_len + extra_len + int(info.compress_size * where)
    data[at:at + 16] = b"\xff" * 16
    archive.write_bytes(bytes(data))


@pytest.mark.parametrize(("method", "raw_error"), [(zipfile.ZIP_DEFLATED, zlib.error),
                                                   (zipfile.ZIP_STORED, zipfile.BadZipFile)])
def test_a_damaged_zip_member_is_named_as_a_damaged_zip(tmp_path, capsys, method, raw_error):
    """A deflate stream broken inside (zlib.error) or a stored member with a CRC mismatch
    (BadZipFile): the zip is reported damaged by name, by the library and by
    'cgvq-study verify' (exit 2)."""
    member = "P01_abc.sqlite"
    payload = b"SQLite format 3\x00" + bytes(random.Random(0).randrange(16)
                                             for _ in range(20000))
    archive = tmp_path / "P01_abc.zip"
    with zipfile.ZipFile(archive, "w", compression=method) as zf:
        zf.writestr(member, payload)
        zf.writestr("SHA256SUMS", f"{hashlib.sha256(payload).hexdigest()}  {member}\n")
    _overwrite_inside(archive, member, 0.1)
    with zipfile.ZipFile(archive) as zf, pytest.raises(raw_error):
        zf.read(member)  # what used to escape as a traceback
    with session_sources([archive]) as (sources, problems):
        assert sources == []
        (problem,) = problems
        assert problem.path == archive
        assert problem.message.startswith("damaged zip: member P01_abc.sqlite cannot be "
                                          "decompressed (")
        assert "ask for the file again" in problem.message
    (report,) = verify_many([archive])
    assert report.state == "damaged" and report.exit_code == 2
    assert main(["verify", str(archive)]) == 2
    captured = capsys.readouterr()
    assert "damaged zip" in captured.out + captured.err
    assert "Traceback" not in captured.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["P01_abc.zip"]  # nothing left behind


def test_a_truncated_export_is_a_damaged_zip_not_a_bad_sqlite_file(tmp_path, capsys):
    path = tmp_path / "P01.sqlite"
    with bare_session(path) as store:
        store.record(0, plain_result(5.0))
    archive = export_session(path, tmp_path / "out")
    archive.write_bytes(archive.read_bytes()[:300])  # cut short in transit
    with session_sources([archive]) as (sources, problems):
        assert sources == []
        (problem,) = problems
        assert "damaged zip" in problem.message and "truncated" in problem.message
    assert main(["verify", str(archive)]) == 2
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "damaged zip" in text and "SQLite" not in text
    assert "Traceback" not in captured.err


def test_a_damaged_ratings_csv_in_an_export_is_damage_of_the_copy(tmp_path, capsys):
    path = tmp_path / "P01.sqlite"
    with bare_session(path) as store:
        for i in range(6):
            store.record(i, plain_result(10.0 * i))
    archive = export_session(path, tmp_path / "out")
    with zipfile.ZipFile(archive) as zf:
        csv_member = next(n for n in zf.namelist() if n.endswith("_ratings.csv"))
    _overwrite_inside(archive, csv_member, 0.5)
    (report,) = verify_many([archive])
    assert report.state == "damaged"
    assert any(csv_member in p.message and "unreadable" in p.message for p in report.problems)
    assert main(["verify", str(archive)]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_a_new_session_file_and_its_folder_are_the_participants_alone(tmp_path):
    """On a shared lab computer a session file (answers, vision results) was readable by
    every account (the default umask's 0644); now 0600, in a folder made 0700."""
    import os
    import stat

    if os.name != "posix":
        pytest.skip("POSIX modes")
    from support.sessions import bare_plan

    from session_store import SessionStore

    folder = tmp_path / "data" / "sessions"
    path = folder / "P01.sqlite"
    with SessionStore.create(path, participant="P01", study_id="s", manifest_sha256=None,
                             seed=1, app_version="t", plan=bare_plan(3)):
        pass
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
