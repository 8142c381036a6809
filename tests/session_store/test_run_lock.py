"""One run per participant: an OS file lock, refused while held, taken over after a crash."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from cgvq_cli.study_cli import main
from session_store.errors import StudyError
from session_store.run_lock import RunLock, lock_path_for, read_holder

REPO = Path(__file__).resolve().parents[2]
HOLDER = """
import sys, time
from pathlib import Path
from session_store.run_lock import RunLock
lock = RunLock(Path(sys.argv[1]), "P01").acquire()
print("locked", flush=True)
time.sleep(60)
"""


def _hold(session: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(session)],
                            env={**os.environ, "PYTHONPATH": str(REPO)},
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_second_process_is_refused_and_a_killed_holders_lock_is_taken_over(tmp_path):
    session = tmp_path / "P01.sqlite"
    holder = _hold(session)
    try:
        with pytest.raises(StudyError, match=rf"already has a run open \(process {holder.pid}"):
            RunLock(session, "P01").acquire()
        assert read_holder(lock_path_for(session))["pid"] == holder.pid
    finally:
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait(timeout=10)
    # The dead process's lock file is still there, but its lock went with the process.
    assert lock_path_for(session).exists()
    lock = RunLock(session, "P01").acquire()
    try:
        assert lock.took_over["pid"] == holder.pid
        assert read_holder(lock_path_for(session))["pid"] == os.getpid()
    finally:
        lock.release()
    assert not lock_path_for(session).exists()


def test_release_and_reacquire_in_one_process(tmp_path):
    session = tmp_path / "P02.sqlite"
    with RunLock(session, "P02") as lock:
        assert lock.held and lock.took_over is None
    assert not lock_path_for(session).exists()
    with RunLock(session, "P02"):
        pass


def test_cgvq_study_run_refuses_a_second_run_at_start(tiny_study, capsys):
    session = tiny_study / "sessions" / "P01.sqlite"
    session.parent.mkdir()
    holder = _hold(session)
    try:
        code = main(["run", str(tiny_study), "--participant", "P01", "--pilot-no-vsync"])
    finally:
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait(timeout=10)
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "already has a run open" in err
    assert not session.exists()
