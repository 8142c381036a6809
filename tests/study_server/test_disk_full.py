"""A full disk under a running server: every upload used to get a 500 and the log a
traceback per request. Now it is a 503 with ``Retry-After`` (the app retries), one log line a
minute, nothing half-stored, and the same upload goes through once space is freed."""

from __future__ import annotations

import asyncio
import errno
import json
import logging
import sqlite3

import pytest
from support.sessions import session_entries

from session_store import utc_now
from session_store.protocol import PROTOCOL
from session_store.sqlite_errors import is_disk_full
from study_server import storage
from study_server.app import create_app
from study_server.config import ServerConfig
from study_server.routes.participants import PREFIX
from study_server.state import ServerState

from .conftest import ADMIN, write_session


def _call(app, method: str, path: str, token: str, body: bytes) -> tuple[int, dict, dict]:
    """One request into the ASGI app: status, headers and the JSON answer."""
    sent: dict = {"body": b""}

    async def receive() -> dict:
        return {"type": "http.request", "body": body, "more_body": False}

    async def send(message: dict) -> None:
        if message["type"] == "http.response.start":
            sent["status"] = message["status"]
            sent["headers"] = {k.decode().lower(): v.decode() for k, v in message["headers"]}
        elif message["type"] == "http.response.body":
            sent["body"] += message.get("body", b"")

    headers = [(b"authorization", f"Bearer {token}".encode()),
               (b"content-type", b"application/json"),
               (b"content-length", str(len(body)).encode())]
    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
             "method": method, "scheme": "http", "path": path, "raw_path": path.encode(),
             "query_string": b"", "root_path": "", "headers": headers,
             "client": ("127.0.0.1", 5555), "server": ("127.0.0.1", 8000)}
    try:
        asyncio.run(app(scope, receive, send))
    except Exception as exc:  # Starlette re-raises what reached the 500 handler, for logging
        sent["headers"]["raised"] = repr(exc)
    return sent["status"], sent["headers"], json.loads(sent["body"] or b"{}")


@pytest.fixture
def full_disk(monkeypatch):
    """Every new connection of the server's database may not grow it: SQLite answers
    SQLITE_FULL ("database or disk is full"), as on a disk with no space left."""
    limit = {"on": False}
    connect = storage._connect

    def limited(path):
        con = connect(path)
        if limit["on"]:
            pages = con.execute("PRAGMA page_count").fetchone()[0]
            con.execute(f"PRAGMA max_page_count = {pages}")
        return con

    monkeypatch.setattr(storage, "_connect", limited)
    return limit


def test_a_full_disk_is_a_503_to_retry_and_one_log_line(served_study, invites, tmp_path,
                                                         monkeypatch, caplog, full_disk):
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    token = {i.participant: i.token for i in invites(2)}["P01"]
    state = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    try:
        state.store.close()  # the connections opened from here on are limited
        full_disk["on"] = True
        path = tmp_path / "P01.sqlite"
        write_session(served_study, path, "P01", ratings=12).close()
        entries = session_entries(path)
        body = json.dumps({"protocol": PROTOCOL, "session_id":
                           entries[0].body["header"]["session_id"], "client_time": utc_now(),
                           "entries": [e.as_json() for e in entries]}).encode()
        app = create_app(state.config, state)
        url = f"{PREFIX.replace('{pid}', 'P01')}/entries"
        caplog.set_level(logging.INFO)
        answers = [_call(app, "POST", url, token, body) for _ in range(3)]
        for status, headers, answer in answers:
            assert status == 503, (status, answer)
            assert int(headers["retry-after"]) >= 1 and "disk is full" in answer["detail"]
        logged = [r for r in caplog.records if r.levelno >= logging.ERROR]
        assert len(logged) == 1 and logged[0].exc_info is None, logged
        assert "disk of the study folder is full" in logged[0].getMessage()
        assert state.store.session_of("P01") is None  # nothing half-stored

        full_disk["on"] = False  # space freed: the same upload goes through, no restart
        state.store.close()
        status, _, answer = _call(app, "POST", url, token, body)
        assert status == 200 and answer["acked_seq"] == entries[-1].seq, answer

        def locked(*args, **kwargs):
            raise sqlite3.OperationalError("database is locked")

        monkeypatch.setattr(state.ingest, "upload", locked)  # any other error: a 500, logged
        caplog.clear()
        status, headers, _ = _call(app, "POST", url, token, body)
        assert status == 500 and "database is locked" in headers["raised"]
        assert [r.exc_info is not None for r in caplog.records if r.levelno >= logging.ERROR
                ] == [True]
    finally:
        state.stop()


def test_only_a_full_disk_counts_as_one():
    con = sqlite3.connect(":memory:")
    con.execute("CREATE TABLE t (x BLOB)")
    con.execute(f"PRAGMA max_page_count = {con.execute('PRAGMA page_count').fetchone()[0]}")
    with pytest.raises(sqlite3.Error) as full:  # SQLite's own SQLITE_FULL
        con.execute("INSERT INTO t VALUES (zeroblob(100000))")
    assert is_disk_full(full.value)
    assert is_disk_full(OSError(errno.ENOSPC, "No space left on device"))
    assert not is_disk_full(sqlite3.OperationalError("database is locked"))
    assert not is_disk_full(OSError(errno.EACCES, "Permission denied"))
    assert not is_disk_full(ValueError("disk is full"))
