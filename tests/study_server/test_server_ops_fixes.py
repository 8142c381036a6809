"""The experimenter's operations beyond the happy path (findings of the server-operations
audit): one server per study folder, a lost database not taken for a new study, a backup that
fails in one line and keeps nothing, a foreign file as the database named, and pull tables
that would replace each other or pulled files refused before anything is fetched."""

from __future__ import annotations

import resource
import shutil
import subprocess
import sys

import pytest

from session_store.errors import StudyError
from study_app.remote.admin import pull
from study_server.storage import state_path

from .conftest import REPO, cli_env, run_cli, write_session


def _one_error_line(proc: subprocess.CompletedProcess) -> str:
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    return lines[0]


@pytest.mark.slow  # about 8 s here: CI runs it after `make test` (.ci/run)
def test_a_second_server_on_the_same_study_is_refused(served_study, server_factory):
    first = server_factory(served_study)
    second = run_cli("serve", str(served_study), "--port", "0", timeout=120)
    assert "this study is served already (process" in _one_error_line(second)
    assert first.alive
    first.stop()
    # once the first has stopped, the study can be served again
    server_factory(served_study).stop()


@pytest.mark.slow  # about 6 s here: CI runs it after `make test` (.ci/run)
@pytest.mark.parametrize("loss", ["missing", "empty"])
def test_a_lost_database_is_not_taken_for_a_new_study(served_study, server_factory, loss):
    server_factory(served_study).stop()
    assert run_cli("backup", str(served_study)).returncode == 0  # into server/backups/
    db = state_path(served_study)
    for extra in ("-wal", "-shm"):
        db.with_name(db.name + extra).unlink(missing_ok=True)
    db.unlink()
    if loss == "empty":
        db.write_bytes(b"")
    proc = run_cli("serve", str(served_study), "--port", "0", timeout=60)
    line = _one_error_line(proc)
    assert f"is {loss}, but this study was served before" in line and "backup" in line
    assert not db.exists() or db.stat().st_size == 0  # nothing new was created in its place


def test_a_backup_onto_a_full_disk_is_one_line_and_keeps_nothing(served_study, tmp_path):
    assert run_cli("invite", str(served_study), "--n", "40", "--out",
                   str(tmp_path / "inv.csv")).returncode == 0
    size = state_path(served_study).stat().st_size
    out = tmp_path / "backups" / "b.sqlite"

    def small_files() -> None:  # the disk fills up part-way through the copy
        resource.setrlimit(resource.RLIMIT_FSIZE, (size // 2, size // 2))

    proc = subprocess.run([sys.executable, "-m", "cgvq_cli.study_cli", "backup",
                           str(served_study), "--out", str(out)], env=cli_env(), cwd=REPO,
                          capture_output=True, text=True, timeout=120, preexec_fn=small_files)
    assert "cannot write the backup" in _one_error_line(proc)
    assert not out.exists() and not list(out.parent.glob("*.partial"))


def test_a_foreign_sqlite_file_as_the_database_is_named(served_study, tmp_path):
    session = tmp_path / "P01.sqlite"
    write_session(served_study, session, "P01", ratings=1).close()
    db = state_path(served_study)
    db.parent.mkdir(exist_ok=True)
    shutil.copy(session, db)  # a mistaken restore
    for command in (["backup", str(served_study), "--out", str(tmp_path / "b.sqlite")],
                    ["withdraw", str(served_study), "P01"]):
        line = _one_error_line(run_cli(*command))
        assert "is not a study-server database; move it away" in line, command


def test_pull_tables_that_would_replace_each_other_or_pulled_files_are_refused(tmp_path):
    out = tmp_path / "pulled"
    nowhere = "http://127.0.0.1:9"  # refused before any request: no server needed
    cases = [({"csv": tmp_path / "t.csv", "answers": tmp_path / "t.csv"}, "a file --answers"),
             ({"csv": tmp_path / "a_screenings.csv", "answers": tmp_path / "a.csv"},
              "a file --answers writes"),
             ({"csv": out / "P01.sqlite"}, "a file pull writes into"),
             ({"answers": out / "server_listing.json"}, "a file pull writes into"),
             ({"csv": out / "manifest.0123456789ab.json"}, "a file pull writes into"),
             ({"csv": tmp_path}, "is a folder")]
    for kwargs, says in cases:
        with pytest.raises(StudyError, match=says):
            pull(nowhere, "x" * 32, out, **kwargs)
    assert not out.exists()


def test_a_finder_file_alone_is_no_trace_of_an_earlier_server(tmp_path):
    from study_server.storage import ServerStore

    db = state_path(tmp_path)
    db.parent.mkdir(parents=True)
    (db.parent / ".DS_Store").write_bytes(b"\0\0\0\1Bud1")  # macOS Finder opened the folder
    ServerStore(db).close()  # a new study's database is created
    db.unlink()
    (db.parent / "backups").mkdir()  # what a served study leaves: refused
    with pytest.raises(StudyError, match="this study was served before"):
        ServerStore(db)
