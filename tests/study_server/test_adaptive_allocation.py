"""An adaptive study through the real server: simulated participants (two to warm up, then
four at once), a server restart, a participant who finishes a block offline, one who tries
to rate a block of their own. The report's DMOS equals a direct fit on the pulled ratings,
the allocation replays identically from its log, and the forged block is refused and
flagged."""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from session_store import TrialResult, read_session, utc_now
from session_store.schedule import block_trials, uniform_block
from study_app.remote import ServerClient, Uploader
from study_app.remote.admin import pull, server_refits
from study_app.remote.participant import request_block
from study_app.simulate import SimulationOptions, UploadOptions, run_simulation

from .conftest import ADMIN, adaptive_session, make_adaptive_study, run_cli

SETTINGS = {"blocks": 3, "warmup_participants": 2, "refit_seconds": 1, "bootstrap": 50}


def _adaptive_study(folder: Path) -> Path:
    return make_adaptive_study(folder, SETTINGS, refs=3, conds=3, file_bytes=256)


def _db(study: Path, sql: str) -> list[tuple]:
    con = sqlite3.connect(f"file:{study / 'server' / 'state.sqlite'}?mode=ro", uri=True)
    try:
        return con.execute(sql).fetchall()
    finally:
        con.close()


def _wait_for(study: Path, sql: str, at_least: int, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if _db(study, sql)[0][0] >= at_least:
            return
        time.sleep(0.2)
    pytest.fail(f"never reached {at_least}: {sql}")


class _Participant:
    """A participant driven by hand: the app's session file, uploader and block request."""

    def __init__(self, study: Path, folder: Path, invite, seed: int) -> None:
        self.invite = invite
        self.items, self.path, self.store = adaptive_session(study, folder,
                                                             invite.participant, seed)
        self.client = ServerClient(invite.server, invite.token)
        self.uploader = Uploader(self.path, self.client, invite.participant,
                                 max_backoff_s=0.5).start()
        self.rng = np.random.default_rng(seed)

    def rate_pending(self) -> None:
        for t in self.store.pending():
            self.store.record(t.index, TrialResult(
                rating=float(self.rng.uniform(20, 90)), rt_ms=3000.0, n_toggles=1,
                ms_on_reference=1000.0, ms_on_test=2000.0, presented_at=utc_now()))
            self.uploader.notify()

    def next_block(self, block: int) -> dict:
        last = self.store.plan()[-1].stimulus
        answer = request_block(self.client, self.invite.participant, self.uploader,
                               self.store.info.session_id, block, last)
        self.store.add_block(block, answer["id"],
                             block_trials(self.items, answer["stimuli"], self.store.plan()),
                             issued_by="server")
        return answer


@pytest.mark.slow  # about 30 s: CI runs it after `make test` (.ci/run), as does `make test-slow`
def test_an_adaptive_study_end_to_end(tmp_path, invites, server_factory):
    study = _adaptive_study(tmp_path / "adaptive")
    inv = invites(7, study=study)
    tokens = {i.participant: i.token for i in inv}
    srv = server_factory(study, "--stats-every", "1")

    assert server_refits(srv.url, ADMIN) == 0  # the experimenter's listing: no refit yet
    # Two participants warm up: no fit yet, their later blocks are uniform.
    first = {p: tokens[p] for p in list(tokens)[:2]}
    run = run_simulation(study / "manifest.json", tmp_path / "warmup",
                         SimulationOptions(raters=2, seed=1), progress=False,
                         upload=UploadOptions(srv.url, first, timeout_s=120))
    assert all(s.all_arrived for s in run.upload.values())
    _wait_for(study, "SELECT count(*) FROM allocation_fits", 1)
    assert server_refits(srv.url, ADMIN) >= 1

    srv.kill()  # a restart: the log and the fit survive in the database
    time.sleep(1.0)
    srv.start()

    # One participant rates block 2 while offline (it was issued before the network went).
    p5 = _Participant(study, tmp_path / "manual", _with_server(inv[4], srv.url), seed=55)
    p5.rate_pending()
    p5.next_block(2)
    p5.uploader.stop()  # offline from here
    p5.rate_pending()
    offline_ratings = len(read_session(p5.path).ratings)

    # Four more at once, adapting to the fit (plus ratings arriving meanwhile).
    later = {p: tokens[p] for p in list(tokens)[2:4] + list(tokens)[5:7]}
    run = run_simulation(study / "manifest.json", tmp_path / "later",
                         SimulationOptions(raters=4, seed=2), progress=False,
                         upload=UploadOptions(srv.url, later, timeout_s=120, pace_s=0.01))
    assert all(s.all_arrived for s in run.upload.values())

    # Back online: the offline block is accepted; the third block comes; done.
    p5.uploader = Uploader(p5.path, p5.client, p5.invite.participant, max_backoff_s=0.5).start()
    p5.next_block(3)
    p5.rate_pending()
    p5.store.finish()
    assert p5.uploader.flush(60).all_arrived
    p5.uploader.stop()
    assert offline_ratings == 2 * 12  # block 2 was rated offline, then all of it arrived

    blocks = _db(study, "SELECT participant, block, fit_id, stimuli FROM allocation_blocks")
    adapted = [json.loads(s) for _, _, fit, s in blocks if fit is not None]
    assert adapted, blocks  # later participants were planned from a fit
    assert any(max(st.count(x) for x in set(st)) > 1 for st in adapted)  # not uniform
    for _, _, fit, s in blocks:
        if fit is None:
            stimuli = json.loads(s)
            assert sorted(stimuli) == sorted({x for x in stimuli})  # uniform: once each

    # The report's DMOS equals a direct fit on the pulled ratings.
    pulled = pull(srv.url, ADMIN, tmp_path / "pulled", csv=tmp_path / "ratings.csv")
    assert len(pulled.sessions) == 7
    frame = pd.read_csv(tmp_path / "ratings.csv")
    assert len(frame) == 7 * (12 + 2 * 12)
    out = tmp_path / "report"
    proc = run_cli_analyze("report", "--ratings", str(tmp_path / "ratings.csv"), "--manifest",
                           str(study / "manifest.json"), "--out", str(out),
                           "--outliers", "none", "--seed", "3")
    assert proc.returncode == 0, proc.stderr
    from analysis import load_ratings
    from analysis.scores import fit_scores

    rs = load_ratings(study / "manifest.json", ratings_csv=tmp_path / "ratings.csv")
    direct = fit_scores(rs, "mle", n_boot=1000, seed=3)
    reported = pd.read_csv(out / "dmos.csv").set_index("stimulus")
    mine = pd.Series(direct.dmos, index=rs.stimulus_ids)
    assert np.allclose(reported.loc[mine.index, "dmos"], mine, atol=1e-9)

    # The allocation replays identically; the log lists every block.
    srv.stop()
    proc = run_cli("allocation", str(study), "--replay")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "identical" in proc.stdout and f"{len(blocks)} block(s)" in proc.stdout


def run_cli_analyze(*args: str):
    import subprocess
    import sys

    from .conftest import REPO, cli_env

    return subprocess.run([sys.executable, "-m", "analysis.cli", *args], env=cli_env(),
                          capture_output=True, text=True, timeout=600, cwd=REPO)


def _with_server(invite, url: str):
    from dataclasses import replace

    return replace(invite, server=url)


def test_a_block_the_server_did_not_issue_is_refused_and_flagged(tmp_path, invites,
                                                                  server_factory):
    study = _adaptive_study(tmp_path / "adaptive")
    inv = invites(1, study=study)
    srv = server_factory(study)
    p = _Participant(study, tmp_path / "local", _with_server(inv[0], srv.url), seed=9)
    p.rate_pending()
    assert p.uploader.flush(30).all_arrived
    # the participant plans block 2 themselves (their favourite stimulus, twelve times)
    favourite = p.items[0].id
    stimuli = uniform_block(p.items, 12, 9, 2, None)
    stimuli = [favourite if k % 2 == 0 else s for k, s in enumerate(stimuli)]
    p.store.add_block(2, "b2-mine", block_trials(p.items, stimuli, p.store.plan()),
                      issued_by="server")
    deadline = time.monotonic() + 20
    while (status := p.uploader.flush(1.0)).state != "refused" and \
            time.monotonic() < deadline:
        time.sleep(0.2)
    p.uploader.stop()
    assert status.state == "refused" and "not issued by this server" in status.error
    flags = _db(study, "SELECT kind, message FROM flags")
    assert ("allocation", "block 2 was not issued by this server") in flags
    assert _db(study, "SELECT count(*) FROM entries WHERE kind='block'") == [(0,)]
    # block 2 as the server plans it is another one: it was never asked for
    assert _db(study, "SELECT count(*) FROM allocation_blocks") == [(0,)]


def test_an_abandoned_session_stops_holding_its_planned_trials(tmp_path, invites,
                                                                monkeypatch):
    """A participant who took their plan and left kept every unrated trial 'pending' for the
    rest of the study, so the planner kept steering away from those stimuli. After an hour
    without an upload only what they rated still counts."""
    from support.sessions import session_entries

    from session_store.protocol import PROTOCOL
    from study_server.config import ServerConfig
    from study_server.state import ServerState

    from .conftest import write_session

    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    study = _adaptive_study(tmp_path / "adaptive")
    (invite,) = invites(1, study=study)
    state = ServerState.open(ServerConfig(study, stats_in_background=False))
    try:
        path = tmp_path / "P01.sqlite"
        store = write_session(study, path, invite.participant, ratings=3)
        rated = [t.stimulus for t in store.plan()[:3]]
        store.close()
        entries = session_entries(path)
        state.ingest.upload(invite.participant, {
            "protocol": PROTOCOL, "session_id": entries[0].body["header"]["session_id"],
            "client_time": utc_now(), "entries": [e.as_json() for e in entries]},
            "127.0.0.1")
        ids = state.allocator.ids
        assert state.allocator.pending({"used": {}}) == dict.fromkeys(ids, 1)  # block 1 open
        with sqlite3.connect(study / "server" / "state.sqlite") as con:
            con.execute("UPDATE sessions SET last_received='2000-01-01T00:00:00.000Z'")
        assert state.allocator.pending({"used": {}}) == dict.fromkeys(rated, 1)
    finally:
        state.stop()
