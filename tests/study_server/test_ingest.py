"""The anchor: what the server acknowledged cannot be rewritten; contradictions, second
sessions, foreign headers are refused, flagged, and write nothing; times and gaps noted."""

from __future__ import annotations

import dataclasses
import json
import sqlite3
from datetime import UTC, datetime, timedelta

import pytest
from support.sessions import session_entries
from support.tamper import edit_database, rewrite_change_log

from session_store import utc_now
from session_store.outbox import entry_hash
from session_store.protocol import PROTOCOL
from study_server.config import ServerConfig
from study_server.ingest import Refused
from study_server.state import ServerState

from .conftest import ADMIN, write_session


@pytest.fixture
def state(served_study, invites, monkeypatch):
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    invites(3)
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    yield st
    st.stop()


def _upload(st, pid, entries, session_id=None):
    return st.ingest.upload(pid, {
        "protocol": PROTOCOL, "session_id": session_id or entries[0].body.get("header", {})
        .get("session_id") or _sid(st, pid), "client_time": utc_now(),
        "entries": [e.as_json() for e in entries]}, "127.0.0.1")


def _sid(st, pid):
    return st.store.session_of(pid).session_id


def _handshake(st, pid, path, problems=(), client_time=None):
    entries = session_entries(path)
    return st.ingest.handshake(pid, {
        "protocol": PROTOCOL, "session_id": entries[0].body["header"]["session_id"],
        "client_time": client_time or utc_now(), "app_version": "t",
        "log_hashes": [e.entry_hash for e in entries], "local_problems": list(problems)},
        "127.0.0.1")


def _snapshot(st):
    sess = st.store.sessions()
    return ([(s.participant, s.acked_seq, s.n_ratings) for s in sess],
            {s.session_id: [e.entry_hash for e in st.store.entries(s.session_id)]
             for s in sess})


def test_uploads_in_pieces_resends_and_the_summary(state, served_study, tmp_path):
    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, "P01", ratings=5).close()
    entries = session_entries(path)
    assert _handshake(state, "P01", path)["acked_seq"] == 0
    assert _upload(state, "P01", entries[:3])["acked_seq"] == 3
    assert _upload(state, "P01", entries[1:6])["acked_seq"] == 6  # overlap: idempotent
    assert _upload(state, "P01", entries)["acked_seq"] == len(entries)
    assert _upload(state, "P01", entries[-2:])["acked_seq"] == len(entries)
    s = state.store.session_of("P01")
    assert (s.n_ratings, s.n_planned, s.finished_at) == (5, 12, None)
    stored = state.store.entries(s.session_id)
    assert [e.entry_hash for e in stored] == [e.entry_hash for e in entries]
    for e in stored:  # server receive time beside the client's own
        assert e.received_at.endswith("Z") and e.client_at is not None
    assert _handshake(state, "P01", path)["acked_seq"] == len(entries)


def test_a_changed_acknowledged_entry_is_refused_and_flagged(state, served_study, tmp_path):
    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, "P01", ratings=4).close()
    entries = session_entries(path)
    _upload(state, "P01", entries)
    before = _snapshot(state)
    rating = next(e for e in entries if e.kind == "rating")
    body = {**rating.body, "row": {**rating.body["row"], "rating": 99.0}}
    forged = type(rating)(rating.seq, rating.kind, body, rating.prev_hash,
                          entry_hash(rating.prev_hash, rating.seq, rating.kind, body))
    with pytest.raises(Refused) as exc:
        _upload(state, "P01", [forged])
    assert exc.value.status == 409 and "differs from the acknowledged" in exc.value.detail
    # the same body change under the old hash (a client that lies about the hash)
    lying = type(rating)(rating.seq, rating.kind, body, rating.prev_hash, rating.entry_hash)
    with pytest.raises(Refused):
        _upload(state, "P01", [lying])
    assert _snapshot(state) == before
    assert [f.kind for f in state.store.flags("P01")] == ["contradiction"]
    assert state.store.flags("P01")[0].count == 2


def test_handshake_compares_the_whole_log(state, served_study, tmp_path):
    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, "P01", ratings=4).close()
    _upload(state, "P01", session_entries(path))
    # the participant rewrites an acknowledged rating in the change log and re-hashes it
    def edit(kind: str, body: dict) -> None:
        if kind == "rating" and body["row"]["seq"] == 2:
            body["row"]["rating"] = 1.0

    rewrite_change_log(path, edit)
    with pytest.raises(Refused, match="differs from the one the server acknowledged"):
        _handshake(state, "P01", path)
    # removed entries (a shorter log) are a contradiction too
    edit_database(path, "DELETE FROM outbox WHERE seq > 5")
    with pytest.raises(Refused):
        _handshake(state, "P01", path)
    kinds = [f.message for f in state.store.flags("P01")]
    assert any("removed after upload" in k for k in kinds)


def test_second_session_foreign_header_and_other_participant(state, served_study, tmp_path):
    first = tmp_path / "a" / "P01.sqlite"
    write_session(served_study, first, "P01", ratings=2).close()
    _upload(state, "P01", session_entries(first))
    before = _snapshot(state)
    again = tmp_path / "b" / "P01.sqlite"  # deleted the file and started again
    write_session(served_study, again, "P01", ratings=3, seed=2).close()
    with pytest.raises(Refused, match="second session"):
        _upload(state, "P01", session_entries(again))
    with pytest.raises(Refused, match="another session"):
        _handshake(state, "P01", again)
    # P02 uploads P01's file with its own (valid) token: the header names P01
    with pytest.raises(Refused, match="belongs to participant 'P01'"):
        _upload(state, "P02", session_entries(first))
    # a session made for another manifest
    other = tmp_path / "c" / "P03.sqlite"
    store = write_session(served_study, other, "P03", ratings=0)
    store.close()
    con = sqlite3.connect(other)
    text = con.execute("SELECT body FROM outbox WHERE seq=1").fetchone()[0]
    con.close()
    entries = session_entries(other)
    body = json.loads(text)
    body["header"]["manifest_sha256"] = "0" * 64
    from session_store.outbox import OutboxEntry, outbox_genesis

    sid = body["header"]["session_id"]
    e1 = OutboxEntry(1, "session", body, outbox_genesis(sid),
                     entry_hash(outbox_genesis(sid), 1, "session", body))
    with pytest.raises(Refused, match="never served"):
        _upload(state, "P03", [e1])
    with pytest.raises(Refused, match="send from entry 1"):
        _upload(state, "P03", entries[1:], session_id=sid)
    assert _snapshot(state) == before
    kinds = {(f.participant, f.kind) for f in state.store.flags()}
    assert {("P01", "second_session"), ("P02", "header"), ("P03", "header")} <= kinds


def test_a_rating_out_of_order_with_a_valid_chain_is_refused(state, served_study, tmp_path):
    """Hashes recomputed by the participant do not help: the server replays the mutations."""
    from session_store.chain import normalise_row, row_hash
    from session_store.outbox import OutboxEntry

    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, "P01", ratings=1).close()
    entries = session_entries(path)
    *head, rating = entries
    _upload(state, "P01", head)
    con = sqlite3.connect(path)
    other = con.execute("SELECT idx, stimulus, repetition FROM plan WHERE idx=3").fetchone()
    con.close()
    row = dict(rating.body["row"])
    row.update(trial=other[0], stimulus=other[1], repetition=other[2])
    row["row_hash"] = row_hash(normalise_row(row))
    body = {**rating.body, "row": row}
    forged = OutboxEntry(rating.seq, "rating", body, rating.prev_hash,
                         entry_hash(rating.prev_hash, rating.seq, "rating", body))
    before = _snapshot(state)
    with pytest.raises(Refused, match="not the next unanswered trial"):
        _upload(state, "P01", [forged])
    assert _snapshot(state) == before
    assert _upload(state, "P01", [rating])["acked_seq"] == len(entries)  # the honest one


def test_clock_skew_local_problems_and_offline_gaps_are_flagged(state, served_study,
                                                                tmp_path):
    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, "P01", ratings=3).close()
    ahead = (datetime.now(UTC) + timedelta(minutes=9)).isoformat()
    answer = _handshake(state, "P01", path, problems=["table ratings differs"],
                        client_time=ahead)
    assert -9.5 * 60000 < answer["clock_offset_ms"] < -8.5 * 60000
    # entries written 20 min ago (by a clock 9 min ahead) arrive now
    old = (datetime.now(UTC) - timedelta(minutes=11)).isoformat()

    def backdate(kind: str, body: dict) -> None:
        if kind in ("event", "preflight", "start"):
            body["at"] = old

    rewrite_change_log(path, backdate)
    _upload(state, "P01", session_entries(path))
    flags = {f.kind: f.message for f in state.store.flags("P01")}
    assert "ahead of the server" in flags["clock_skew"]
    assert "table ratings differs" in flags["local_edit"]
    assert "entries 2-4 arrived up to 20 min after" in flags["offline_gap"]
    assert state.store.participant("P01").last_address == "127.0.0.1"


@pytest.mark.parametrize("payload, status", [
    ({}, 422),
    ({"protocol": "cgvq-upload/0", "session_id": "x", "client_time": "t", "entries": []}, 422),
    ({"protocol": PROTOCOL, "session_id": "../x", "client_time": "t", "entries": [{}]}, 422),
    ({"protocol": PROTOCOL, "session_id": "abc", "client_time": "t",
      "entries": [{"seq": True, "kind": "rating", "body": {}, "prev_hash": "0" * 64,
                   "entry_hash": "0" * 64}]}, 422),
    ({"protocol": PROTOCOL, "session_id": "abc", "client_time": "t",
      "entries": [{"seq": 1, "kind": "drop_table", "body": {}, "prev_hash": "0" * 64,
                   "entry_hash": "0" * 64}]}, 422),
    ([1, 2, 3], 422),
])
def test_malformed_uploads_write_nothing(state, payload, status):
    with pytest.raises(Refused) as exc:
        state.ingest.upload("P01", payload, "127.0.0.1")
    assert exc.value.status == status
    assert state.store.sessions() == [] and state.store.flags() == []


def test_an_evicted_replica_stays_usable_by_the_upload_holding_it(state, served_study,
                                                                   tmp_path):
    """The replica cache evicts under its own lock, not the owner's: an upload of P01 that
    holds P01's replica while P02's upload evicts it must still be able to use it."""
    state.ingest.limits = dataclasses.replace(state.ingest.limits, cached_sessions=1)
    files = {}
    for pid in ("P01", "P02"):
        files[pid] = tmp_path / f"{pid}.sqlite"
        write_session(served_study, files[pid], pid, ratings=2).close()
    first = session_entries(files["P01"])
    _upload(state, "P01", first[:2])
    held = state.ingest._replica(state.store.session_of("P01"))  # as P01's upload holds it
    _upload(state, "P02", session_entries(files["P02"]))  # evicts P01's replica
    assert held.head()[0] == 2  # not closed under its user
    _upload(state, "P01", first[2:])
    assert state.store.session_of("P01").acked_seq == len(first)
