"""The server database: schema versions and migrations, online backup, withdrawal."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path

import pytest
from support.tamper import edit_database

from session_store.errors import StudyError
from study_server.storage import (
    MIGRATIONS,
    SCHEMA_VERSION,
    ServerStore,
    StoredEntry,
    schema_version,
)


def _entry(seq: int, kind: str = "event") -> StoredEntry:
    return StoredEntry(seq, kind, '{"at":"2026-01-01T00:00:00.000Z"}', f"{seq - 1:064x}",
                       f"{seq:064x}", "2026-01-01T00:00:00.000Z", "2026-01-01T00:00:01.000Z")


def _v1_database(path: Path) -> None:
    """A database as the first server version wrote it, with data in every table."""
    ServerStore(path, target_version=1).close()
    con = sqlite3.connect(path)
    con.executescript("""
        INSERT INTO versions VALUES ('aa', 'study', x'7b7d', '2026-01-01T00:00:00Z', 1);
        INSERT INTO participants VALUES ('P01', 'hash1', '2026-01-01T00:00:00Z', NULL, 12.5);
        INSERT INTO sessions VALUES ('s1', 'P01', 'aa', 't', '2026-01-01', '2026-01-01',
            '2026-01-01', 1, 'h', 0, 12, NULL, NULL);
        INSERT INTO entries VALUES ('s1', 1, 'session', '{}', 'p', 'h', NULL, '2026-01-01');
        INSERT INTO flags (participant, session_id, kind, message, at)
            VALUES ('P01', 's1', 'clock_skew', 'off by 9 min', '2026-01-02T00:00:00Z');
    """)
    con.commit()
    con.close()


def test_fresh_database_runs_every_migration(tmp_path):
    path = tmp_path / "state.sqlite"
    with ServerStore(path) as store:
        assert store.found_version == 0 and store.schema_version == SCHEMA_VERSION
        assert SCHEMA_VERSION == len(MIGRATIONS) >= 2
        con = sqlite3.connect(path)
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        con.close()


def test_migration_from_version_1_keeps_the_data(tmp_path):
    path = tmp_path / "state.sqlite"
    _v1_database(path)
    con = sqlite3.connect(path)
    assert schema_version(con) == 1
    con.close()
    with ServerStore(path) as store:
        assert store.found_version == 1 and store.schema_version == SCHEMA_VERSION
        p = store.participant("P01")
        assert p is not None and p.clock_offset_ms == 12.5 and p.last_address is None
        assert [e.kind for e in store.entries("s1")] == ["session"]
        [flag] = store.flags("P01")
        assert (flag.count, flag.last_at) == (1, "2026-01-02T00:00:00Z")  # filled by v2
        store.add_flag("P01", "s1", "clock_skew", "off by 9 min", "2026-01-03T00:00:00Z")
        [flag] = store.flags("P01")
        assert (flag.count, flag.first_at, flag.last_at) == (
            2, "2026-01-02T00:00:00Z", "2026-01-03T00:00:00Z")
    with ServerStore(path) as again:  # idempotent
        assert again.found_version == SCHEMA_VERSION


def test_failing_migration_leaves_the_database_as_it_was(tmp_path, monkeypatch):
    path = tmp_path / "state.sqlite"
    _v1_database(path)

    def broken(con: sqlite3.Connection) -> None:
        con.execute("ALTER TABLE participants ADD COLUMN last_address TEXT")
        raise sqlite3.OperationalError("disk I/O error (simulated)")

    import study_server.storage as storage

    monkeypatch.setattr(storage, "MIGRATIONS", (storage.MIGRATIONS[0], broken))
    with pytest.raises(StudyError, match="not a readable SQLite database"):
        ServerStore(path)
    con = sqlite3.connect(path)
    assert schema_version(con) == 1
    columns = [r[1] for r in con.execute("PRAGMA table_info(participants)")]
    assert "last_address" not in columns
    con.close()


def test_newer_or_foreign_databases_are_refused(tmp_path):
    path = tmp_path / "state.sqlite"
    ServerStore(path).close()
    edit_database(path, f"UPDATE meta SET value='{SCHEMA_VERSION + 1}' WHERE key='schema'")
    with pytest.raises(StudyError, match="newer than this toolkit"):
        ServerStore(path)
    other = tmp_path / "other.sqlite"
    edit_database(other, "CREATE TABLE x (a)")
    with pytest.raises(StudyError, match="not a study-server database"):
        ServerStore(other)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"not a database at all" * 100)
    with pytest.raises(StudyError, match="not a readable SQLite database"):
        ServerStore(junk)


def _store_with_session(path: Path) -> ServerStore:
    store = ServerStore(path)
    store.set_current_version("aa", "study", b"{}", "2026-01-01T00:00:00Z")
    store.add_participants([("P01", "h1"), ("P02", "h2")], "2026-01-01T00:00:00Z")
    return store


def test_backup_while_writing_is_consistent(tmp_path):
    path = tmp_path / "state.sqlite"
    store = _store_with_session(path)
    stop = threading.Event()
    written = []

    def writer() -> None:
        seq = 0
        state = {"n_ratings": 0, "n_planned": 10, "finished_at": None, "closed_as": None}
        while not stop.is_set() and seq < 3000:
            seq += 1
            store.store_entries(participant="P01", session_id="s1", entries=[_entry(seq)],
                                state=state, new_session={"manifest_sha256": "aa",
                                                          "app_version": "t",
                                                          "created_at": "x"}
                                if seq == 1 else None)
            written.append(seq)

    t = threading.Thread(target=writer)
    t.start()
    try:
        while len(written) < 50:
            stop.wait(0.01)
        backups = [store.backup(tmp_path / f"b{i}.sqlite") for i in range(3)]
    finally:
        stop.set()
        t.join(timeout=60)
    store.close()
    for b in backups:
        with ServerStore(b, create=False) as copy:
            entries = copy.entries("s1")
            seqs = [e.seq for e in entries]
            assert seqs == list(range(1, len(seqs) + 1)) and seqs  # a prefix, no holes
            assert copy.session_of("P01").acked_seq == len(seqs)  # header agrees with rows
    with pytest.raises(StudyError, match="exists already"):
        ServerStore(path).backup(backups[0])


def test_withdraw_deletes_rows_and_keeps_a_tombstone(tmp_path):
    path = tmp_path / "state.sqlite"
    with _store_with_session(path) as store:
        state = {"n_ratings": 0, "n_planned": 10, "finished_at": None, "closed_as": None}
        store.store_entries(participant="P01", session_id="s1", entries=[_entry(1), _entry(2)],
                            state=state, new_session={"manifest_sha256": "aa",
                                                      "app_version": "t", "created_at": "x"})
        store.add_flag("P01", "s1", "clock_skew", "off", "2026-01-01T00:00:00Z")
        store.touch("P01", "2026-01-01T00:00:00Z", "192.0.2.7")
        stone = store.withdraw("P01", "2026-01-05T00:00:00Z", "asked by e-mail")
        assert stone.entries_deleted == 2
        assert store.participant("P01") is None and store.session_of("P01") is None
        assert store.entries("s1") == [] and store.flags("P01") == []
        assert store.tombstone("P01") == stone
        # an upload that raced the withdrawal flags nothing afterwards
        assert store.add_flag("P01", "s1", "refused", "late", "2026-01-05T00:00:01Z") is False
        assert store.flags("P01") == []
        assert store.participant("P02") is not None
        with pytest.raises(StudyError, match="withdrawn already"):
            store.withdraw("P01", "2026-01-06T00:00:00Z", "again")
        with pytest.raises(StudyError, match="exists already"):  # the id is not reused
            store.add_participants([("P01", "h3")], "2026-01-07T00:00:00Z")
        assert store.checkpoint()
    raw = path.read_bytes() + (Path(f"{path}-wal").read_bytes()
                               if Path(f"{path}-wal").exists() else b"")
    assert b"192.0.2.7" not in raw  # overwritten, not just unlinked (secure_delete)


def test_the_server_database_asks_for_full_fsync(tmp_path):
    """As session files: on macOS fsync() alone stops at the drive's cache."""
    with ServerStore(tmp_path / "server.sqlite") as store:
        con = store._con()
        assert [con.execute(f"PRAGMA {p}").fetchone()[0]
                for p in ("synchronous", "fullfsync", "checkpoint_fullfsync")] == [2, 1, 1]
