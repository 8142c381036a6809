"""The audit's findings on the study server, each shown fixed: bounded body reads, uploads
whose content contradicts the study, statistics that survive one bad session, a cache no
client can grow, 4xx (not 500) for malformed input, per-address login limits."""

from __future__ import annotations

import asyncio
import gc
import json
import os
import re
import stat
import time
import tracemalloc
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.sessions import session_entries

from session_store import utc_now
from session_store.outbox import OutboxEntry, entry_hash, outbox_genesis
from session_store.protocol import PROTOCOL
from study_server import auth
from study_server.app import create_app
from study_server.config import ServerConfig
from study_server.ingest import Refused
from study_server.state import ServerState
from study_server.stats import participant_stats

from .conftest import ADMIN, write_session


@pytest.fixture
def state(served_study, invites, monkeypatch):
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    tokens = {i.participant: i.token for i in invites(3)}
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    st.tokens = tokens  # for the tests that go through HTTP
    yield st
    st.stop()


# -- helpers ----------------------------------------------------------------------------
def _rechain(entries: list[OutboxEntry], session_id: str) -> list[OutboxEntry]:
    """Hashes recomputed after editing bodies (what any participant can do)."""
    out, prev = [], outbox_genesis(session_id)
    for e in entries:
        h = entry_hash(prev, e.seq, e.kind, e.body)
        out.append(OutboxEntry(e.seq, e.kind, e.body, prev, h))
        prev = h
    return out


def _upload(st: ServerState, pid: str, entries: list[OutboxEntry]) -> dict:
    sid = entries[0].body["header"]["session_id"] if entries[0].kind == "session" else \
        st.store.session_of(pid).session_id
    return st.ingest.upload(pid, {"protocol": PROTOCOL, "session_id": sid,
                                  "client_time": utc_now(),
                                  "entries": [e.as_json() for e in entries]}, "127.0.0.1")


def _edited(entries: list[OutboxEntry], seq: int, body: dict) -> list[OutboxEntry]:
    """The log with entry ``seq``'s body replaced, re-chained."""
    sid = entries[0].body["header"]["session_id"]
    changed = [OutboxEntry(e.seq, e.kind, body if e.seq == seq else e.body, "", "")
               for e in entries]
    return _rechain(changed, sid)


def _refused(st: ServerState, pid: str, entries: list[OutboxEntry]) -> Refused:
    with pytest.raises(Refused) as exc:
        _upload(st, pid, entries)
    return exc.value


@pytest.fixture
def genuine(state, served_study, tmp_path) -> list[OutboxEntry]:
    """P01's genuine log: header and plan, pre-flight, consent, start, 3 ratings."""
    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, "P01", ratings=3).close()
    return session_entries(path)


class Asgi:
    """One request straight into the ASGI app, counting the body bytes the app consumed."""

    def __init__(self, app) -> None:
        self.app = app
        self.body = b""
        """The last response's body."""

    def request(self, method: str, path: str, headers: list[tuple[bytes, bytes]],
                chunks: Iterator[bytes]) -> tuple[int, int]:
        consumed = 0
        status = 0

        async def receive() -> dict:
            nonlocal consumed
            chunk = next(chunks, None)
            if chunk is None:
                return {"type": "http.request", "body": b"", "more_body": False}
            consumed += len(chunk)
            return {"type": "http.request", "body": chunk, "more_body": True}

        self.body = b""

        async def send(message: dict) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            elif message["type"] == "http.response.body":
                self.body += message.get("body", b"")

        scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
                 "method": method, "scheme": "http", "path": path, "raw_path": path.encode(),
                 "query_string": b"", "root_path": "", "headers": headers,
                 "client": ("127.0.0.1", 5555), "server": ("127.0.0.1", 8000),
                 "app": self.app}
        asyncio.run(self.app(scope, receive, send))
        return status, consumed


def _stream(total: int, chunk: int = 16384) -> Iterator[bytes]:
    sent = 0
    while sent < total:
        sent += chunk
        yield b"t" * chunk


# -- finding 1: every body is read bounded -----------------------------------------------
def test_login_stops_reading_a_streamed_body_past_its_limit(state):
    app = Asgi(create_app(state.config, state))
    status, consumed = app.request("POST", "/dashboard/login", [], _stream(20 << 20))
    assert status == 413
    assert consumed <= 4096 + 16384  # stopped at the limit: never the 20 MiB sent


def test_login_refuses_a_declared_oversized_body_without_reading(state):
    app = Asgi(create_app(state.config, state))
    status, consumed = app.request("POST", "/dashboard/login",
                                   [(b"content-length", str(20 << 20).encode())],
                                   _stream(20 << 20))
    assert (status, consumed) == (413, 0)
    status, _ = app.request("POST", "/dashboard/login", [(b"content-length", "²".encode())],
                            _stream(10))
    assert status == 400


@pytest.mark.parametrize("what", ["handshake", "entries", "block"])
def test_participant_routes_stop_reading_past_the_body_limit(state, what):
    app = Asgi(create_app(state.config, state))
    headers = [(b"authorization", f"Bearer {state.tokens['P01']}".encode())]
    status, consumed = app.request("POST", f"/api/v1/participants/P01/{what}", headers,
                                   _stream(8 << 20))
    assert status == 413
    assert consumed <= state.config.max_body_bytes + 16384


# -- finding 13: a stranger's wrong logins do not lock the experimenter out ----------------
def test_wrong_logins_are_limited_per_address(state):
    app = create_app(state.config, state)

    pages: list[bytes] = []

    def login(token: str, client: str) -> int:
        body = f"token={token}".encode()
        status = 0

        async def receive() -> dict:
            return {"type": "http.request", "body": body, "more_body": False}

        async def send(message: dict) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            elif message["type"] == "http.response.body":
                pages.append(message.get("body", b""))

        scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
                 "method": "POST", "scheme": "http", "path": "/dashboard/login",
                 "raw_path": b"/dashboard/login", "query_string": b"", "root_path": "",
                 "headers": [(b"content-length", str(len(body)).encode())],
                 "client": (client, 5555), "server": ("127.0.0.1", 8000), "app": app}
        asyncio.run(app(scope, receive, send))
        return status

    answers = [login("wrong", "10.0.0.9") for _ in range(12)]
    assert answers[0] == 403 and answers[-1] == 429
    assert login(ADMIN, "10.0.0.1") == 303  # the experimenter, from elsewhere
    assert login(ADMIN, "10.0.0.9") == 429  # the guesser's address waits
    # and is told how long (the limit allows one more try every few seconds, not a minute)
    wait = re.search(rb"try again in (\d+) s\.", pages[-1])
    assert wait is not None and 1 <= int(wait.group(1)) <= 10


# -- finding 9: malformed input is a 4xx, never a 500 -----------------------------------
@pytest.mark.parametrize("cookie", ["\u00b2.x", "99999999999.\u00b2", "1.2.3", "."])
def test_odd_admin_cookies_are_unauthenticated_not_errors(state, cookie):
    app = Asgi(create_app(state.config, state))
    headers = [(b"cookie", f"cgvq_admin={cookie}".encode("latin-1"))]
    for path in ("/dashboard", "/api/v1/admin/sessions"):
        status, _ = app.request("GET", path, headers, iter(()))
        assert status == 401
        if path == "/dashboard":  # a cookie that no longer opens the page: says why
            assert b"Your login has expired; log in again." in app.body
    app.request("GET", "/dashboard", [], iter(()))
    assert b"expired" not in app.body  # no cookie: the plain login form


@pytest.mark.parametrize("client_time", ["9999-12-31T23:59:59-23:59",
                                         "0001-01-01T00:00:00+23:59"])
def test_a_client_time_out_of_range_is_no_time(state, client_time):
    answer = state.ingest.handshake("P01", {
        "protocol": PROTOCOL, "session_id": None, "client_time": client_time,
        "app_version": "t", "log_hashes": [], "local_problems": []}, "127.0.0.1")
    assert answer["acked_seq"] == 0 and answer["clock_offset_ms"] is None


def test_an_allocation_check_that_fails_is_a_refusal(state, genuine):
    def broken(*_args):
        return int("abc")

    state.ingest.check_allocation = broken
    exc = _refused(state, "P01", genuine)
    assert exc.status == 409 and "malformed" in exc.detail
    assert state.store.sessions() == []


# -- findings 3 and 9: wrong JSON types are refused at upload --------------------------
@pytest.mark.parametrize("seq, change, where", [
    (1, lambda b: {**b, "settings": ["timing_mode", "vsync"]}, "settings"),
    (1, lambda b: {**b, "header": {**b["header"], "seed": "abc"}}, "header.seed"),
    (1, lambda b: {**b, "header": {**b["header"], "seed": 2**70}}, "header.seed"),
    (1, lambda b: {**b, "plan": [[0, ["x"], "r", 1, 0]]}, "plan row 0"),
    (2, lambda b: {**b, "results": {"name": "x"}}, "results"),
    (3, lambda b: {**b, "at": {"x": 1}}, "at"),
    (3, lambda b: {**b, "kind": ["pause"]}, "kind"),
    (3, lambda b: {**b, "details": [1, 2]}, "details"),
    (4, lambda b: {**b, "display": "vsync"}, "display"),
    (5, lambda b: {**b, "presentation": {**b["presentation"], "details": [1]}},
     "presentation.details"),
    (5, lambda b: {**b, "row": {**b["row"], "rt_ms": "fast"}}, "row.rt_ms"),
])
def test_wrong_json_types_are_refused_and_write_nothing(state, genuine, seq, change, where):
    kinds = [e.kind for e in genuine]
    assert kinds[:5] == ["session", "preflight", "event", "start", "rating"]
    entries = _edited(genuine, seq, change(genuine[seq - 1].body))
    exc = _refused(state, "P01", entries)
    assert exc.status == 422 and where in exc.detail
    assert state.store.sessions() == []
    assert [f.kind for f in state.store.flags("P01")] == ["content"]


def test_one_unreadable_session_does_not_stop_the_statistics():
    good = json.dumps({"row": {"rt_ms": 2000.0, "n_toggles": 2, "rating": 50.0}})
    rows = [("P01", "s", "session", json.dumps({"settings": ["x"]}), "a"),
            ("P01", "s", "start", json.dumps({"display": "vsync"}), "a"),
            ("P01", "s", "requeue", json.dumps({"presentation": []}), "a"),
            ("P01", "s", "rating", "[1]", "a"),
            ("P02", "s", "rating", good, "b")]
    stats = participant_stats(rows)
    assert stats["P02"].n_ratings == 1 and stats["P02"].median_trial_s == 2.0
    assert stats["P02"].unreadable == 0
    assert stats["P01"].unreadable == 1  # the list body; the others read as empty objects


# -- finding 2: content that contradicts the study is refused --------------------------
def test_ratings_outside_the_scale_are_refused(state, genuine):
    assert _upload(state, "P01", genuine[:4])["acked_seq"] == 4
    body = genuine[4].body
    for bad in (-1_000_000.0, 100.5):
        forged = {**body, "row": {**body["row"], "rating": bad}}
        entries = _edited(genuine, 5, forged)
        exc = _refused(state, "P01", entries[4:5])
        assert exc.status == 422 and "outside the scale 0..100" in exc.detail
    assert state.store.session_of("P01").n_ratings == 0


def _plan_body(genuine: list[OutboxEntry], plan: list[list], **settings) -> dict:
    body = genuine[0].body
    return {**body, "plan": plan, "settings": {**body["settings"], **settings}}


def test_plans_the_study_does_not_give_are_refused(state, genuine):
    plan = genuine[0].body["plan"]
    first = plan[0]
    one_stimulus = [[k, first[1], first[2], k + 1, first[4]] for k in range(50)]
    unknown = [[0, "SRC99_HRC01", first[2], 1, 0], *plan[1:]]
    flipped = [[*first[:4], 1 - first[4]], *plan[1:]]
    half = plan[:len(plan) // 2]
    cases = {"equally often": one_stimulus, "does not have": unknown,
             "hidden-reference flag": flipped}
    for expected, bad in cases.items():
        exc = _refused(state, "P01", _edited(genuine, 1, _plan_body(genuine, bad))[:1])
        assert exc.status == 422 and expected in exc.detail, exc.detail
    if len({row[1] for row in half}) < len({row[1] for row in plan}):
        exc = _refused(state, "P01", _edited(genuine, 1, _plan_body(genuine, half))[:1])
        assert exc.status == 422
    assert state.store.sessions() == []


def test_a_simulated_session_may_use_its_own_repetitions(state, genuine):
    """``cgvq-study simulate --server --repetitions 1`` on a study of 2 repetitions."""
    plan = [row for row in genuine[0].body["plan"] if row[3] == 1]
    plan = [[k, *row[1:]] for k, row in enumerate(plan)]
    exc = _refused(state, "P01", _edited(genuine, 1, _plan_body(genuine, plan))[:1])
    assert exc.status == 422 and "this study plans 2" in exc.detail
    simulated = _edited(genuine, 1, _plan_body(genuine, plan, simulated=True))[:1]
    assert _upload(state, "P01", simulated)["acked_seq"] == 1


def test_a_block_in_a_study_without_blocks_is_refused(state, genuine):
    _upload(state, "P01", genuine)
    last = genuine[-1]
    first = genuine[0].body["plan"][0]
    block = {"at": utc_now(), "block": 2, "id": "b", "issued_by": "session",
             "trials": [[first[1], first[2], 3, bool(first[4])]]}
    body = OutboxEntry(last.seq + 1, "block", block, last.entry_hash,
                       entry_hash(last.entry_hash, last.seq + 1, "block", block))
    exc = _refused(state, "P01", [body])
    assert exc.status == 422 and "blocks" in exc.detail


# -- finding 4: refused uploads do not grow the server's memory -------------------------
def test_refused_uploads_with_made_up_manifests_leave_no_memory_behind(state, genuine):
    def attempt(k: int) -> None:
        header = {**genuine[0].body["header"], "manifest_sha256": f"{k:08d}" + "f" * 100_000}
        answer = OutboxEntry(2, "answer", {"at": utc_now(), "questionnaire": "q",
                                           "question": "a", "value": 1, "page": 0}, "", "")
        entries = _rechain([OutboxEntry(1, "session", {**genuine[0].body, "header": header},
                                        "", ""), answer], header["session_id"])
        with pytest.raises(Refused) as exc:
            _upload(state, "P01", entries)
        assert exc.value.status == 409

    attempt(0)
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(1, 41):  # 4 MB of made-up shas
            attempt(k)
        gc.collect()
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 1_000_000


# -- finding 8: the database, its backups and pulled sessions are the owner's only -------
@pytest.fixture
def open_umask():
    """A umask of 022 (files 0644 by default), as on most systems; restored after."""
    old = os.umask(0o022)
    yield
    os.umask(old)


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_database_and_backups_are_owner_only(open_umask, tmp_path):
    from study_server.storage import ServerStore

    db = tmp_path / "study" / "server" / "state.sqlite"
    store = ServerStore(db)
    try:
        store.add_flag("P01", None, "test", "x", utc_now())  # a write: the WAL exists
        backup = store.backup(db.parent / "backups" / "state-1.sqlite")
    finally:
        store.close()
    assert _mode(db.parent) == 0o700 and _mode(db) == 0o600
    assert _mode(backup.parent) == 0o700 and _mode(backup) == 0o600
    for suffix in ("-wal", "-shm"):
        extra = Path(f"{db}{suffix}")
        if extra.exists():
            assert _mode(extra) == 0o600


def test_an_older_database_is_tightened_when_opened(open_umask, tmp_path):
    from study_server.storage import ServerStore

    db = tmp_path / "server" / "state.sqlite"
    ServerStore(db).close()
    db.chmod(0o644)
    db.parent.chmod(0o755)
    ServerStore(db).close()
    assert (_mode(db.parent), _mode(db)) == (0o700, 0o600)


def test_pulled_sessions_are_owner_only(open_umask, served_study, invites, server_factory,
                                        tmp_path):
    from study_app.remote import ServerClient, sync_session
    from study_app.remote.admin import pull

    inv = invites(1)[0]
    srv = server_factory(served_study)
    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, inv.participant, ratings=2).close()
    sync_session(path, ServerClient(srv.url, inv.token), inv.participant)
    out = tmp_path / "returned"
    result = pull(srv.url, ADMIN, out, csv=out / "ratings.csv")
    assert _mode(out) == 0o700
    assert [_mode(s.path) for s in result.sessions] == [0o600]
    assert _mode(result.listing_path) == 0o600 and _mode(out / "ratings.csv") == 0o600


def test_a_logout_outlives_a_restart_and_cookies_expire(state):
    """The last logout is kept in the server's database: after a restart a cookie from
    before it still opens nothing; any cookie stops after its lifetime."""
    before = auth.make_cookie(ADMIN)
    app = Asgi(create_app(state.config, state))
    cookie = [(b"cookie", f"{auth.COOKIE}={before}".encode())]
    assert app.request("GET", "/dashboard", cookie, iter(()))[0] == 200
    assert app.request("POST", "/dashboard/logout", cookie, iter(()))[0] == 303
    after = auth.make_cookie(ADMIN, logged_out_ms=state.dashboard_logout_ms)
    state.stop()
    reopened = ServerState.open(state.config)
    try:
        app = Asgi(create_app(reopened.config, reopened))
        assert app.request("GET", "/dashboard", cookie, iter(()))[0] == 401
        assert b"Your login has expired" in app.body
        fresh = [(b"cookie", f"{auth.COOKIE}={after}".encode())]
        assert app.request("GET", "/dashboard", fresh, iter(()))[0] == 200
    finally:
        reopened.stop()
    day_old = auth.make_cookie(ADMIN, now=time.time() - auth.COOKIE_LIFETIME_S - 1)
    assert not auth.cookie_valid(ADMIN, day_old)
    assert auth.cookie_valid(ADMIN, auth.make_cookie(ADMIN, now=time.time() - 60))
    assert not auth.cookie_valid("another admin token", auth.make_cookie(ADMIN))


def test_a_refused_batch_is_flagged_in_one_sentence(state, genuine):
    """The flag read "upload refused: upload refused: entry 16 ..." (the replica's words were
    prefixed a second time)."""
    _upload(state, "P01", genuine[:4])
    exc = _refused(state, "P01", [genuine[5]])  # entry 5 left out: the chain does not go on
    assert exc.status == 409
    [flag] = [f for f in state.store.flags() if f.kind == "refused"]
    assert flag.message.startswith("upload refused: ") and flag.message.count("refused") == 1
    assert exc.detail == flag.message
