"""Many participants at once through a real server: every rating exactly once, a SIGKILLed
server restarted, an outage ridden out, a backup taken while serving."""

from __future__ import annotations

import sqlite3
import threading
import time
from pathlib import Path

import pytest
from support.sessions import session_tables

from session_store import read_session, verify_session
from study_app.remote.admin import pull
from study_app.simulate import SimulationOptions, UploadOptions, run_simulation

from .conftest import ADMIN, make_served_study, run_cli


def _assert_all_arrived_once(local_dir: Path, pulled_dir: Path, participants: list[str],
                             n_trials: int) -> None:
    for pid in participants:
        local, pulled = local_dir / f"{pid}.sqlite", pulled_dir / f"{pid}.sqlite"
        assert session_tables(pulled) == session_tables(local), pid  # identical, row for row
        report = verify_session(pulled)
        assert report.complete and report.n_ratings == n_trials, (pid, report.problems)
        trials = [r["trial"] for r in read_session(pulled).ratings]
        assert len(trials) == len(set(trials)) == n_trials


@pytest.mark.slow  # about 65 s: CI runs it after `make test` (.ci/run), as does `make test-slow`
def test_twenty_participants_240_ratings_each_at_once(tmp_path, invites, server_factory):
    study = make_served_study(tmp_path / "big", refs=20, conds=3, repetitions=3,
                              file_bytes=512)
    inv = invites(20, study=study)
    srv = server_factory(study, "--stats-every", "5")
    backups: list[Path] = []
    stop = threading.Event()

    def back_up() -> None:  # the experimenter backs up while everyone uploads
        while not stop.is_set() and len(backups) < 3:
            stop.wait(3)
            out = tmp_path / f"backup{len(backups)}.sqlite"
            proc = run_cli("backup", str(study), "--out", str(out))
            assert proc.returncode == 0, proc.stderr
            backups.append(out)

    t = threading.Thread(target=back_up)
    t.start()
    try:
        result = run_simulation(
            study / "manifest.json", tmp_path / "local", SimulationOptions(raters=20, seed=5),
            progress=False, upload=UploadOptions(srv.url, {i.participant: i.token for i in inv},
                                                 timeout_s=300))
    finally:
        stop.set()
        t.join(timeout=120)
    assert all(s.all_arrived for s in result.upload.values()), result.upload
    pulled = pull(srv.url, ADMIN, tmp_path / "pulled", csv=tmp_path / "ratings.csv")
    assert len(pulled.sessions) == 20 and pulled.n_csv_rows == 20 * 240
    _assert_all_arrived_once(tmp_path / "local", tmp_path / "pulled",
                             [i.participant for i in inv], 240)
    assert backups
    for b in backups:
        con = sqlite3.connect(b)
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        per_session = con.execute(
            "SELECT s.acked_seq, count(e.seq), max(e.seq) FROM sessions s LEFT JOIN entries e "
            "USING (session_id) GROUP BY s.session_id").fetchall()
        con.close()
        assert all(a == n == m for a, n, m in per_session)  # consistent, no holes


def _paced_panel(tmp_path, invites, server_factory, n: int):
    study = make_served_study(tmp_path / "paced", refs=4, conds=2, repetitions=2,
                              file_bytes=256)  # 12 stimuli x 2 = 24 trials
    inv = invites(n, study=study)
    srv = server_factory(study)
    return study, inv, srv


def _run_in_thread(study, out, inv, url, pace, opts=None):
    box: dict = {}

    def work() -> None:
        try:
            box["result"] = run_simulation(
                study / "manifest.json", out, opts or SimulationOptions(raters=len(inv), seed=2),
                progress=False, upload=UploadOptions(url, {i.participant: i.token for i in inv},
                                                     pace_s=pace, timeout_s=240,
                                                     max_backoff_s=2.0))
        except BaseException as exc:  # reported by the test
            box["error"] = exc

    t = threading.Thread(target=work)
    t.start()
    return t, box


# about 11 s: CI runs it after `make test` (.ci/run), as `make test-slow` does
@pytest.mark.slow
def test_sigkill_mid_study_then_restart_loses_nothing(tmp_path, invites, server_factory):
    study, inv, srv = _paced_panel(tmp_path, invites, server_factory, 4)
    t, box = _run_in_thread(study, tmp_path / "local", inv, srv.url, pace=0.15)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # wait until ratings have arrived
        con = sqlite3.connect(f"file:{study}/server/state.sqlite?mode=ro", uri=True)
        n = con.execute("SELECT count(*) FROM entries WHERE kind='rating'").fetchone()[0]
        con.close()
        if n >= 10:
            break
        time.sleep(0.2)
    srv.kill()  # SIGKILL mid-study
    assert not srv.alive
    time.sleep(2.0)
    srv.start()  # same port: the clients find it again by themselves
    t.join(timeout=300)
    assert "error" not in box, box.get("error")
    assert all(s.all_arrived for s in box["result"].upload.values()), box["result"].upload
    pull(srv.url, ADMIN, tmp_path / "pulled")
    _assert_all_arrived_once(tmp_path / "local", tmp_path / "pulled",
                             [i.participant for i in inv], 24)


@pytest.mark.parametrize("outage_s", [
    pytest.param(4.0, id="4s", marks=pytest.mark.slow),  # about 14 s here: CI runs it
    pytest.param(30.0, id="30s", marks=pytest.mark.slow),
])
def test_server_down_clients_queue_and_catch_up(tmp_path, invites, server_factory, outage_s):
    study, inv, srv = _paced_panel(tmp_path, invites, server_factory, 3)
    pace = max(outage_s / 12, 0.1)  # the outage falls mid-study
    t0 = time.monotonic()
    t, box = _run_in_thread(study, tmp_path / "local", inv, srv.url, pace=pace)
    time.sleep(pace * 5)
    srv.stop()
    down_at = time.monotonic()
    local = tmp_path / "local"
    counts_before = _local_ratings(local, inv)
    time.sleep(outage_s)
    counts_after = _local_ratings(local, inv)
    srv.start()
    t.join(timeout=300)
    assert "error" not in box, box.get("error")
    # the participants kept rating while the server was down (the app never waits)
    assert all(counts_after[p] - counts_before[p] >= int(outage_s / pace) - 3
               for p in counts_before), (counts_before, counts_after)
    assert all(s.all_arrived for s in box["result"].upload.values())
    pull(srv.url, ADMIN, tmp_path / "pulled")
    _assert_all_arrived_once(local, tmp_path / "pulled", [i.participant for i in inv], 24)
    assert down_at - t0 < 24 * pace  # the outage really was mid-study


def _local_ratings(folder: Path, inv) -> dict[str, int]:
    out = {}
    for i in inv:
        p = folder / f"{i.participant}.sqlite"
        out[i.participant] = len(read_session(p).ratings) if p.exists() else 0
    return out
