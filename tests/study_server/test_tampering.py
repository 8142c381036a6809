"""A participant edits their file after upload, in every way the verify tests know plus a
recomputed chain: the server flags it (dashboard and pull) and its copy stays unchanged."""

from __future__ import annotations

import contextlib
import re
import sqlite3
from pathlib import Path

import pytest
from support.sessions import session_tables
from support.tamper import edit_database, recompute_rating_chain, rewrite_change_log

from session_store.errors import StudyError
from session_store.schema import open_existing
from study_app.remote import ServerClient, ServerRefused, sync_session

from .conftest import ADMIN, raw_request, run_cli, write_session


def _sql(*statements: str):
    return lambda path: edit_database(path, *statements)


def _remove_tail_and_fix_header(path: Path) -> None:
    con = sqlite3.connect(path)
    head = con.execute("SELECT row_hash FROM ratings WHERE seq=8").fetchone()[0]
    con.execute("DELETE FROM ratings WHERE seq > 8")
    con.execute("UPDATE session SET n_ratings=8, head_hash=?, finished_at=NULL", (head,))
    con.commit()
    con.close()


def _rewrite_change_log(path: Path) -> None:
    """The thorough forger: rating 2 edited in the tables, the rating chain and the change
    log, every hash recomputed, and the upload state reset so that everything is re-sent."""
    recompute_rating_chain(path)
    con = sqlite3.connect(path)
    ratings = {r[0]: r for r in con.execute("SELECT seq, rating, prev_hash, row_hash FROM "
                                            "ratings")}
    con.close()

    def follow_the_tables(kind: str, body: dict) -> None:
        if kind == "rating":
            n = body["row"]["seq"]
            body["row"].update(rating=ratings[n][1], prev_hash=ratings[n][2],
                               row_hash=ratings[n][3])

    rewrite_change_log(path, follow_the_tables)
    edit_database(path, "UPDATE upload_state SET value='0' WHERE key='acked_seq'")


EDITS = {
    "edited rating": _sql("UPDATE ratings SET rating = 95 WHERE seq = 2"),
    "edited response time": _sql("UPDATE ratings SET rt_ms = 5 WHERE seq = 1"),
    "edited participant": _sql("UPDATE session SET participant = 'P99'"),
    "deleted row": _sql("DELETE FROM ratings WHERE seq = 4"),
    "removed tail, header updated": _remove_tail_and_fix_header,
    "edited pre-flight": _sql("UPDATE session SET preflight = '[]', preflight_skipped = 1"),
    "recomputed rating chain": recompute_rating_chain,
    "edited change log": _sql("UPDATE outbox SET body = replace(body, '\"skipped\":false', "
                              "'\"skipped\":true') WHERE kind = 'preflight'"),
    "rewritten change log, re-hashed": _rewrite_change_log,
    "schema version changed": _sql("UPDATE meta SET value = 'cgvq-session/2' "
                                   "WHERE key = 'schema'"),
}


@pytest.mark.slow  # about 7 s here: CI runs it after `make test` (.ci/run)
def test_edits_after_upload_are_flagged_and_the_server_copy_is_unchanged(
        served_study, tmp_path, invites, server_factory):
    inv = invites(len(EDITS))
    srv = server_factory(served_study)
    originals = {}
    for (name, edit), i in zip(EDITS.items(), inv, strict=True):
        path = tmp_path / "local" / f"{i.participant}.sqlite"
        write_session(served_study, path, i.participant, ratings=12, finish=True).close()
        client = ServerClient(srv.url, i.token)
        assert sync_session(path, client, i.participant).complete
        originals[i.participant] = (name, session_tables(path))
        edit(path)
        with contextlib.suppress(ServerRefused, StudyError):  # the app, started again
            sync_session(path, client, i.participant)
    # pull: every edited participant is flagged, every copy is the one acknowledged
    proc = run_cli("pull", srv.url, "--admin-token", ADMIN, "--out", str(tmp_path / "pulled"))
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    status, _, page = raw_request(srv.url, "GET", "/dashboard",
                                  headers={"Authorization": f"Bearer {ADMIN}"})
    assert status == 200
    html = page.decode()
    for pid, (name, tables) in originals.items():
        block = re.search(rf"^  {pid}: .*?(?=^  P\d\d: |\Z)", out, re.S | re.M).group(0)
        assert "complete" in block.splitlines()[0], (name, block)
        assert "FLAG " in block, (name, block)
        assert session_tables(tmp_path / "pulled" / f"{pid}.sqlite") == tables, name
        row = re.search(rf'<tr [^>]*data-participant="{pid}"[^>]*>.*?</tr>', html,
                        re.S).group(0)
        assert 'class="flag"' in row, name
    assert f"{len(EDITS)} participant(s) flagged" in out
    kinds = re.findall(r"FLAG (\w+)", out)
    assert {"local_edit", "contradiction"} <= set(kinds)


@pytest.mark.parametrize("name", ["rewritten change log, re-hashed"])
def test_a_rewritten_log_is_refused_entry_by_entry(name, served_study, tmp_path, invites,
                                                   server_factory):
    """Even a client that skips its own checks (no handshake comparison) cannot replace an
    acknowledged entry: the upload itself is refused."""
    from session_store import utc_now
    from session_store.outbox import read_entries
    from session_store.protocol import PROTOCOL

    [i] = invites(1)
    srv = server_factory(served_study)
    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, "P01", ratings=12, finish=True).close()
    client = ServerClient(srv.url, i.token)
    sync_session(path, client, "P01")
    EDITS[name](path)
    con = open_existing(path, readonly=True)
    entries = read_entries(con)
    con.close()
    with pytest.raises(ServerRefused) as exc:
        client.json("POST", "/api/v1/participants/P01/entries", {
            "protocol": PROTOCOL, "session_id": entries[0].body["header"]["session_id"],
            "client_time": utc_now(), "entries": [e.as_json() for e in entries[:100]]})
    assert exc.value.status == 409 and "differs from the acknowledged" in exc.value.detail
