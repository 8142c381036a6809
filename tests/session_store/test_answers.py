"""Questionnaire answers and vision-check results in the session file: stored in the change
log (the outbox chain) like ratings, read back, replayed, refused after a withdrawal, and
tabled for the export."""

from __future__ import annotations

import json
import sqlite3

import pytest
from support.sessions import bare_session, plain_result, session_entries

from session_store import StudyError, read_session
from session_store.answers import answer_rows, latest_answers, screening_rows
from session_store.replica import tables_match_outbox


def test_answers_are_chained_read_back_and_the_last_one_counts(tmp_path):
    path = tmp_path / "P01.sqlite"
    with bare_session(path, n=2) as store:
        store.record_answer("demographics", "age", 34, page=0, ms=2100.0)
        store.record_answer("demographics", "gender", "prefer-not-to-say", page=0)
        store.record_answer("demographics", "age", 43, page=0, ms=900.0)  # went back
        store.record_screening("colour", "failed", {"errors": {"protan": 2}, "plates": 6})
        store.record(0, plain_result(50))
        store.record(1, plain_result(60))
        store.finish()
        # the post-study survey comes after the last trial
        store.record_answer("post_study", "comments", "<script>alert(1)</script>", page=1)
    record = read_session(path)
    assert record.intact
    assert [(a["question"], a["value"]) for a in record.answers] == [
        ("age", 34), ("gender", "prefer-not-to-say"), ("age", 43),
        ("comments", "<script>alert(1)</script>")]
    latest = latest_answers(record.answers)
    assert latest[("demographics", "age")]["value"] == 43
    rows = answer_rows(record)
    assert [(r["question"], json.loads(r["value"])) for r in rows] == [
        ("age", 43), ("gender", "prefer-not-to-say"), ("comments", "<script>alert(1)</script>")]
    assert {r["participant"] for r in rows} == {"P01"}
    assert record.screenings[0]["outcome"] == "failed"
    assert json.loads(screening_rows(record)[0]["result"]) == {"errors": {"protan": 2},
                                                               "plates": 6}
    kinds = [e.kind for e in session_entries(path)]
    assert kinds.count("answer") == 4 and kinds.count("screening") == 1
    assert tables_match_outbox(path) == []


def test_an_answer_edited_outside_the_app_is_found(tmp_path):
    path = tmp_path / "P01.sqlite"
    with bare_session(path) as store:
        store.record_answer("demographics", "age", 34, page=0)
    con = sqlite3.connect(path)
    con.execute("UPDATE answers SET value='21'")
    con.commit()
    con.close()
    assert tables_match_outbox(path) == [
        "table answers differs from the change log (edited outside the app)"]


def test_no_answers_after_a_withdrawal_and_malformed_changes_refused(tmp_path):
    path = tmp_path / "P01.sqlite"
    with bare_session(path) as store:
        with pytest.raises(StudyError, match="outcome 'maybe' is not one of"):
            store.record_screening("colour", "maybe", {})
        with pytest.raises(StudyError, match="ms must be a non-negative number"):
            store.record_answer("d", "age", 3, page=0, ms=-5)
        store.withdraw()
        with pytest.raises(StudyError, match="withdrew; the session accepts no answers"):
            store.record_answer("post_study", "comments", "hi", page=0)
    assert read_session(path).answers == []


def test_a_file_older_than_the_panel_tables_reads_and_takes_answers(tmp_path):
    path = tmp_path / "P01.sqlite"
    bare_session(path).close()
    con = sqlite3.connect(path)
    con.execute("DROP TABLE answers")
    con.execute("DROP TABLE screenings")
    con.commit()
    con.close()
    record = read_session(path)
    assert record.answers == [] and record.screenings == [] and record.intact
    assert tables_match_outbox(path) == []
    from session_store import SessionStore

    with SessionStore.open(path) as store:
        store.record_answer("demographics", "age", 30, page=0)
    assert [a["value"] for a in read_session(path).answers] == [30]
