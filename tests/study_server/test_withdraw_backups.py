"""``withdraw`` deleted a participant on the server but said only that backups "made before
now" still held them: the experimenter had to find which, and deleting a whole backup would
have destroyed everyone else's data with it."""

from __future__ import annotations

import sqlite3

from cgvq_cli.study_cli import main
from session_store import utc_now
from session_store.outbox import read_entries
from session_store.protocol import PROTOCOL
from session_store.schema import open_existing
from study_server.config import ServerConfig
from study_server.operations import backup, withdraw
from study_server.state import ServerState

from .conftest import ADMIN, make_served_study, write_session


def _participants(db):
    with sqlite3.connect(db) as con:
        who = {r[0] for r in con.execute("SELECT participant FROM participants")}
        n = con.execute("SELECT count(*) FROM entries").fetchone()[0]
    return who, n


def test_withdraw_names_the_backups_holding_them_and_purges_only_them(
        tmp_path, invites, monkeypatch, capsys):
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    study = make_served_study(tmp_path / "s", refs=2, conds=1, file_bytes=64)
    invites(3, study=study)
    st = ServerState.open(ServerConfig(study, stats_in_background=False))
    try:
        for pid in ("P01", "P02"):
            path = tmp_path / f"{pid}.sqlite"
            write_session(study, path, pid, ratings=3).close()
            con = open_existing(path, readonly=True)
            entries = read_entries(con)
            con.close()
            st.ingest.upload(pid, {"protocol": PROTOCOL, "client_time": utc_now(),
                                   "session_id": entries[0].body["header"]["session_id"],
                                   "entries": [e.as_json() for e in entries]}, None)
    finally:
        st.stop()
    old = backup(study, study / "server" / "backups" / "state-1.sqlite")
    before = _participants(old)
    assert {"P01", "P02"} <= before[0]

    assert main(["withdraw", str(study), "P01"]) == 0
    out = capsys.readouterr().out
    assert f"1 backup(s) still hold this participant's data: {old}" in out
    assert "--purge-backups' deletes them there" in out
    assert _participants(old) == before  # named, not touched

    # once withdrawn, a second run purges the backups only
    assert main(["withdraw", str(study), "P01", "--purge-backups"]) == 0
    out = capsys.readouterr().out
    assert "withdrawn before; only the backups were searched" in out
    assert f"deleted from the backup {old}" in out
    who, n = _participants(old)
    assert "P01" not in who and "P02" in who and 0 < n < before[1]  # P02's entries stay
    w = withdraw(study, "P01", purge_backups=True)  # nothing left to find
    assert w.backups_purged == [] and w.backups_holding == []
