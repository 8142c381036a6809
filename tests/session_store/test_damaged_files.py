"""Damaged session files never crash a reader (findings 2, 6, 7 and 9 of the session audit):
verify reports DAMAGED with exit 2, one bad file in a folder does not stop the report for the
others, export exits 2 for a damaged file, a read-only folder's -wal is read, and a player's
session without a consent record is flagged."""

from __future__ import annotations

import random
import sqlite3
from pathlib import Path

import pytest
from support.sessions import bare_session, plain_result

import session_store.schema as schema
from cgvq_cli.study_cli import main
from session_store import SessionStore, read_session, verify_session
from session_store.errors import StudyError
from study_app.export import verify_many

N_DAMAGED_COPIES = 30


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A small finished session with a change log, checkpointed into one file."""
    path = tmp_path_factory.mktemp("orig") / "P01.sqlite"
    with bare_session(path, n=6) as store:
        store.save_preflight([{"name": "screen", "ok": True, "message": "ok"}], skipped=False)
        store.log_event("consent", consent_sha256=None)
        store.mark_started(display={"w": 1920})
        for i in range(6):
            store.record(i, plain_result(3.5 * i))
        store.finish()
    return path


def _damage(data: bytes, seed: int) -> bytes:
    rnd = random.Random(seed)
    out = bytearray(data)
    for _ in range(rnd.randint(1, 3)):
        out[rnd.randrange(len(out))] = rnd.randrange(256)
    return bytes(out)


@pytest.mark.parametrize("seed", range(N_DAMAGED_COPIES))
def test_random_byte_damage_is_damaged_or_intact_never_a_crash(finished, tmp_path, capsys,
                                                               seed):
    want = [(r["trial"], r["rating"]) for r in read_session(finished).ratings]
    path = tmp_path / "P01.sqlite"
    path.write_bytes(_damage(finished.read_bytes(), seed))
    code = main(["verify", str(path)])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    if code == 0:  # the damage fell on unused bytes: the same ratings
        assert [(r["trial"], r["rating"]) for r in read_session(path).ratings] == want
    else:
        assert code == 2, out + err
        assert "DAMAGED" in out and err.count("\n") == 1 and "error:" in err
    code = main(["export", str(path), "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err and code in (0, 2), out + err
    assert code == 0 or err.count("\n") == 1


def _change_log_body_damaged(path: Path) -> None:
    """One control character in a change-log body: its JSON no longer parses."""
    con = sqlite3.connect(path)
    con.execute("UPDATE outbox SET body = substr(body, 1, 5) || char(1) || substr(body, 6) "
                "WHERE seq = 3")
    con.commit()
    con.close()


def _body_not_utf8(path: Path) -> None:
    con = sqlite3.connect(path)
    con.execute("UPDATE outbox SET body = CAST(X'7B22ff' AS TEXT) WHERE seq = 2")
    con.commit()
    con.close()


@pytest.mark.parametrize("damage", [_change_log_body_damaged, _body_not_utf8])
def test_one_bad_file_in_a_folder_does_not_stop_the_others(finished, tmp_path, capsys, damage):
    returns = tmp_path / "returns"
    returns.mkdir()
    (returns / "P01.sqlite").write_bytes(finished.read_bytes())
    (returns / "P02.sqlite").write_bytes(finished.read_bytes())
    damage(returns / "P02.sqlite")
    reports = verify_many([returns])
    assert [r.state for r in reports] == ["complete", "damaged"]
    assert main(["verify", str(returns)]) == 2
    out, err = capsys.readouterr()
    assert "P01.sqlite: intact and complete" in out and "P02.sqlite: DAMAGED" in out
    assert "Traceback" not in err and err.count("\n") == 1
    report = verify_session(returns / "P02.sqlite")
    assert report.exit_code == 2 and "change log" in report.problems[0].message


def test_export_of_a_damaged_file_exits_2_after_writing_the_zip(finished, tmp_path, capsys):
    path = tmp_path / "P01.sqlite"
    path.write_bytes(finished.read_bytes())
    _change_log_body_damaged(path)
    assert main(["export", str(path), "--out", str(tmp_path / "out")]) == 2
    out, err = capsys.readouterr()
    assert "DAMAGED" in out and "was written anyway" in err and err.count("\n") == 1
    assert len(list((tmp_path / "out").glob("*.zip"))) == 1


def test_a_malformed_file_without_its_wal_says_to_ask_for_the_wal(tmp_path):
    path = tmp_path / "P01.sqlite"
    data = bytearray(b"SQLite format 3\x00" + bytes(4096))
    path.write_bytes(bytes(data))
    with pytest.raises(StudyError, match=r"P01\.sqlite-wal .* ask for that file too"):
        verify_session(path)


def test_a_read_only_folder_still_reads_the_wal(tmp_path, monkeypatch, capsys):
    """Where the folder cannot be written (a USB stick, a read-only share) SQLite cannot read
    the -wal in place; the reader reads both from a private copy instead of dropping it."""
    path = tmp_path / "P01.sqlite"
    store = bare_session(path)
    store.record(0, plain_result(1.0))
    store._checkpoint = lambda **_: None  # the next two ratings stay in the WAL
    store.record(1, plain_result(2.0))
    store.record(2, plain_result(3.0))
    held = sqlite3.connect(path)  # keeps the -wal when the writer closes
    held.execute("SELECT count(*) FROM ratings").fetchone()
    store._con.close()

    def read_only_medium(p: Path) -> sqlite3.Connection:
        raise sqlite3.OperationalError("unable to open database file")

    monkeypatch.setattr(schema, "_open_read_only", read_only_medium)
    assert len(read_session(path).ratings) == 3
    report = verify_session(path)
    assert report.n_ratings == 3 and any("-wal" in w for w in report.warnings)
    assert main(["export", str(path), "--out", str(tmp_path / "out")]) == 0
    assert "(3 of 6 ratings" in capsys.readouterr().out
    held.close()


def test_creation_stores_preflight_and_consent_in_one_transaction(tmp_path, monkeypatch):
    path = tmp_path / "P01.sqlite"
    store = SessionStore.create(
        path, participant="P01", study_id="s", manifest_sha256=None, seed=1, app_version="t",
        plan=[p for p in read_plan()], settings={"timing_mode": "vsync"},
        preflight=[{"name": "screen", "ok": True, "message": "ok"}],
        events=[("consent", {"asked": True}), ("created", {"pid": 1})])
    store.close()
    kinds = [e["kind"] for e in read_session(path).events]
    assert kinds == ["preflight", "consent", "created"]
    assert verify_session(path).warnings == []

    import session_store.writer as writer

    calls = []

    def fail_at_consent(con, kind, body, session_id):
        calls.append(kind)
        if body.get("kind") == "consent":
            raise KeyboardInterrupt  # a kill between the records
        return real(con, kind, body, session_id)

    real = writer.append_to_outbox
    monkeypatch.setattr(writer, "append_to_outbox", fail_at_consent)
    other = tmp_path / "P02.sqlite"
    with pytest.raises(KeyboardInterrupt):
        SessionStore.create(other, participant="P02", study_id="s", manifest_sha256=None,
                            seed=1, app_version="t", plan=read_plan(),
                            preflight=[], events=[("consent", {})])
    assert calls == ["session", "preflight", "event"] and not other.exists()


def read_plan():
    from support.sessions import bare_plan

    return bare_plan(3)


def test_verify_flags_a_player_session_without_consent(tmp_path):
    path = tmp_path / "P01.sqlite"
    with SessionStore.create(path, participant="P01", study_id="s", manifest_sha256=None,
                             seed=1, app_version="t", plan=read_plan(),
                             settings={"timing_mode": "vsync"}) as store:
        store.save_preflight([], skipped=True)  # an older app killed before the consent
    report = verify_session(path)
    assert any("no consent record" in w for w in report.warnings)
    assert verify_session(_simulated(tmp_path)).warnings == []


def _simulated(tmp_path: Path) -> Path:
    path = tmp_path / "S01.sqlite"
    bare_session(path, participant="S01").close()  # not the player's: no consent asked
    return path


def test_dropping_the_change_log_is_damage(finished, tmp_path, capsys):
    path = tmp_path / "P01.sqlite"
    path.write_bytes(finished.read_bytes())
    con = sqlite3.connect(path)
    con.execute("DROP TABLE outbox")
    con.commit()
    con.close()
    assert main(["verify", str(path)]) == 2
    assert "change log (outbox) is missing" in capsys.readouterr().out


def test_dropping_the_change_log_and_its_upload_table_is_damage_too(finished, tmp_path, capsys):
    """With both tables gone the file looked like one older than the change log, and an
    edit with a recomputed rating chain passed; every writer creates the change log with the
    file, so its absence is damage whatever else is there."""
    path = tmp_path / "P01.sqlite"
    path.write_bytes(finished.read_bytes())
    con = sqlite3.connect(path)
    con.execute("DROP TABLE outbox")
    con.execute("DROP TABLE upload_state")
    con.commit()
    con.close()
    assert main(["verify", str(path)]) == 2
    assert "change log (outbox) is missing" in capsys.readouterr().out
