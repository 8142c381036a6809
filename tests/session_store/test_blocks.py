"""Blocks of an adaptive study: appended to the plan only when the plan so far is answered,
numbered in order, in the change log (a replica rebuilt from it has the same tables), and
refused after the session closed or from an unknown issuer."""

from __future__ import annotations

import pytest
from support.sessions import bare_session, plain_result, session_entries, session_tables

from session_store import read_session
from session_store.errors import StudyError
from session_store.replica import Replica

BLOCK = [("S2", "R", 2, False), ("S0", "R", 2, False)]


def test_a_block_extends_the_plan_and_is_replayed_by_a_replica(tmp_path):
    path = tmp_path / "P01.sqlite"
    with bare_session(path, n=3) as store:
        with pytest.raises(StudyError, match="only when every planned trial is answered"):
            store.add_block(2, "b2", BLOCK, issued_by="server")
        for k in range(3):
            store.record(k, plain_result(10.0 * k))
        assert store.blocks_done() == 1
        added = store.add_block(2, "b2", BLOCK, issued_by="server")
        assert [(p.index, p.stimulus, p.repetition) for p in added] == [(3, "S2", 2),
                                                                       (4, "S0", 2)]
        assert store.next_trial().index == 3 and store.progress() == (3, 5)
        assert store.blocks_done() == 2
        with pytest.raises(StudyError, match="block 4 does not follow block 2"):
            store.record(3, plain_result(50.0))
            store.record(4, plain_result(60.0))
            store.add_block(4, "b4", BLOCK, issued_by="server")
        with pytest.raises(StudyError, match="issued_by"):
            store.add_block(3, "b3", BLOCK, issued_by="me")
        store.finish()
        with pytest.raises(StudyError):
            store.add_block(3, "b3", BLOCK, issued_by="server")
    record = read_session(path)
    assert [r["stimulus"] for r in record.ratings] == ["S0", "S1", "S2", "S2", "S0"]
    [block] = [e for e in record.events if e["kind"] == "block"]
    assert (block["block"], block["id"], block["issued_by"], block["first"],
            block["trials"]) == (2, "b2", "server", 3, 2)
    entries = session_entries(path)
    copy = tmp_path / "replica.sqlite"
    replica = Replica.create(copy, entries[0])
    replica.accept(entries[1:])
    replica.close()
    assert session_tables(copy) == session_tables(path)
