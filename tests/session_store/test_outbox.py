"""The outbox (a hash-chained log of every change) and the replica a server builds from it."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from support.sessions import session_entries, session_tables
from support.tamper import edit_database, recompute_rating_chain

from session_store import (
    ContradictionError,
    PlannedTrial,
    Replica,
    SessionStore,
    TrialResult,
    read_session,
    tables_match_outbox,
    verify_session,
)
from session_store.chain import canonical
from session_store.errors import StudyError
from session_store.outbox import OutboxEntry, entry_hash


def _result(v: float, dropped: int = 0) -> TrialResult:
    return TrialResult(rating=v, rt_ms=900.0 + v, n_toggles=2, ms_on_reference=400.0,
                       ms_on_test=500.5, presented_at="2026-01-01T10:00:00.000Z",
                       slider_first_move_ms=700.0, frames_presented=90, dropped_frames=dropped,
                       max_flip_interval_ms=17.1, switch_latencies_ms=[516.7],
                       details={"vsync": True, "viewing_ms": 2900.0})


def _full_session(path: Path) -> Path:
    plan = [PlannedTrial(i, f"S{i % 3}", "R", i // 3 + 1, i % 3 == 0) for i in range(5)]
    store = SessionStore.create(path, participant="P01", study_id="s", manifest_sha256="ab" * 32,
                                seed=3, app_version="t", plan=plan,
                                settings={"timing_mode": "vsync"})
    with store:
        store.save_preflight([{"name": "screen_size", "ok": True, "message": "ok"}],
                             skipped=False)
        store.log_event("consent", consent_sha256="c" * 64, briefing_sha256="b" * 64)
        store.mark_started(display={"vsync": True, "refresh_hz": 60.0})
        store.record(0, _result(10.0))
        store.requeue(1, _result(0.0, dropped=12), "12 dropped frames > 10")
        store.record(2, _result(30.0))
        store.log_event("pause", trial=3)
        for trial in (3, 4, 5):
            store.record(trial, _result(40.0 + trial))
        store.finish()
    return path


def test_a_replica_built_in_batches_equals_the_original(tmp_path):
    original = _full_session(tmp_path / "P01.sqlite")
    entries = session_entries(original)
    assert [e.kind for e in entries][:4] == ["session", "preflight", "event", "start"]
    assert entries[-1].kind == "finish"
    replica = Replica.create(tmp_path / "server" / "P01.sqlite", entries[0])
    with replica:
        assert replica.accept(entries[1:4]) == 4
        assert replica.accept(entries[1:6]) == 6  # a re-send overlapping the acked ones
        assert replica.accept(entries[6:]) == len(entries)
        assert replica.accept(entries[6:]) == len(entries)  # idempotent
    copy = tmp_path / "server" / "P01.sqlite"
    assert session_tables(copy) == session_tables(original)
    report = verify_session(copy)
    assert report.intact and report.complete and report.n_ratings == 5
    rec = read_session(copy)
    assert rec.info.settings == {"timing_mode": "vsync"} and rec.n_requeued == 1
    assert [e["kind"] for e in rec.events].count("consent") == 1


def test_replica_refuses_contradictions_gaps_and_forgeries(tmp_path):
    entries = session_entries(_full_session(tmp_path / "P01.sqlite"))
    path = tmp_path / "server.sqlite"
    with Replica.create(path, entries[0]) as replica:
        replica.accept(entries[1:6])
        before = session_tables(path)
        # an acknowledged entry edited (and its chain recomputed by the participant)
        e = entries[4]
        body = {**e.body, "row": {**e.body["row"], "rating": 99.0}}
        forged = OutboxEntry(e.seq, e.kind, body, e.prev_hash,
                             entry_hash(e.prev_hash, e.seq, e.kind, body))
        with pytest.raises(ContradictionError, match="differs from the acknowledged"):
            replica.accept([forged, *entries[5:8]])
        # a gap
        with pytest.raises(StudyError, match="where 7 was expected"):
            replica.accept(entries[7:9])
        # a new rating whose row hash does not match its content (entry chain recomputed)
        e = entries[6]
        assert e.kind == "rating"
        body = {**e.body, "row": {**e.body["row"], "rating": 1.0}}
        forged = OutboxEntry(e.seq, e.kind, body, e.prev_hash,
                             entry_hash(e.prev_hash, e.seq, e.kind, body))
        with pytest.raises(StudyError, match="does not match its hash"):
            replica.accept([forged])
        assert session_tables(path) == before  # nothing of a refused batch was stored
        assert replica.accept(entries[6:]) == len(entries)


def test_edits_with_a_recomputed_chain_are_caught_by_the_change_log(tmp_path):
    path = _full_session(tmp_path / "P01.sqlite")
    assert tables_match_outbox(path) == []
    recompute_rating_chain(path)
    assert read_session(path).problems == []  # the rating chain alone cannot tell
    assert tables_match_outbox(path) == [
        "table session differs from the change log (edited outside the app)",
        "table ratings differs from the change log (edited outside the app)"]
    assert verify_session(path).exit_code == 2


def test_removed_tail_with_updated_header_and_edited_preflight_are_caught(tmp_path):
    path = _full_session(tmp_path / "P01.sqlite")
    con = sqlite3.connect(path)
    head = con.execute("SELECT row_hash FROM ratings WHERE seq=3").fetchone()[0]
    con.execute("DELETE FROM ratings WHERE seq > 3")
    con.execute("UPDATE session SET n_ratings=3, head_hash=?, finished_at=NULL", (head,))
    con.execute("UPDATE session SET preflight=?", (canonical([{"name": "x", "ok": True}]),))
    con.commit()
    con.close()
    assert read_session(path).problems == []  # looks like an honest incomplete session
    diffs = tables_match_outbox(path)
    assert "table session differs from the change log (edited outside the app)" in diffs
    assert "table ratings differs from the change log (edited outside the app)" in diffs
    report = verify_session(path)
    assert not report.intact and report.state == "damaged"


def test_an_edited_change_log_breaks_its_own_chain(tmp_path):
    path = _full_session(tmp_path / "P01.sqlite")
    edit_database(path, "UPDATE outbox SET body=replace(body, '\"skipped\":false', "
                        "'\"skipped\":true') WHERE kind='preflight'")
    assert tables_match_outbox(path) == [
        "the change log is broken: entry 2's content does not match its hash"]
