"""The HTTP surface under a real uvicorn on 127.0.0.1: tokens, ids, sizes, garbage, rate
limits, admin and dashboard access. A refused request writes nothing; the server keeps
serving."""

from __future__ import annotations

import json

import pytest

from session_store.protocol import PROTOCOL
from study_app.remote import ServerClient, ServerRefused, sync_session

from .conftest import ADMIN, db_dump, make_served_study, raw_request, write_session


@pytest.fixture(scope="module")
def running(tmp_path_factory):
    """One server for this module: a study with P01..P03 invited, P01 with a session."""
    from session_store.invite import read_invites
    from study_server.operations import invite

    from .conftest import RunningServer

    tmp = tmp_path_factory.mktemp("http")
    study = make_served_study(tmp / "study")
    invite(study, 3, tmp / "invites.csv")
    tokens = {i.participant: i.token for i in read_invites(tmp / "invites.csv")}
    srv = RunningServer(study, ["--rate", "5", "--burst", "40"]).start()
    session = tmp / "P01.sqlite"
    write_session(study, session, "P01", ratings=3).close()
    sync_session(session, ServerClient(srv.url, tokens["P01"]), "P01")
    yield srv, study, tokens, session
    srv.kill()


def _alive(srv) -> None:
    status, _, body = raw_request(srv.url, "GET", "/healthz")
    assert status == 200 and json.loads(body)["ok"] is True


def _handshake_body(session_id=None) -> bytes:
    return json.dumps({"protocol": PROTOCOL, "session_id": session_id,
                       "client_time": "2026-01-01T00:00:00Z", "app_version": "t",
                       "log_hashes": [], "local_problems": []}).encode()


def test_wrong_or_other_tokens_are_refused_and_write_nothing(running, tmp_path):
    srv, study, tokens, _ = running
    before = db_dump(study)
    path = tmp_path / "P02.sqlite"
    write_session(study, path, "P02", ratings=2).close()
    cases = [("P02", None, 401), ("P02", "x" * 32, 403), ("P02", tokens["P01"], 403),
             ("P09", tokens["P01"], 403)]
    for pid, token, status in cases:
        headers = {"Content-Type": "application/json"}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        got, _, _ = raw_request(srv.url, "POST", f"/api/v1/participants/{pid}/handshake",
                                _handshake_body(), headers)
        assert got == status, (pid, token)
    with pytest.raises(ServerRefused) as exc:  # the real client, with P01's token for P02
        sync_session(path, ServerClient(srv.url, tokens["P01"]), "P02")
    assert exc.value.status == 403
    with pytest.raises(ServerRefused):
        ServerClient(srv.url, tokens["P01"]).json("GET", "/api/v1/participants/P02/study")
    assert db_dump(study) == before
    _alive(srv)


@pytest.mark.parametrize("path", [
    "/api/v1/participants/..%2F..%2Fserver/handshake",
    "/api/v1/participants/../admin/sessions",
    "/api/v1/participants/.hidden/handshake",
    "/api/v1/participants/P%2001/handshake",
    "/api/v1/participants/" + "x" * 300 + "/handshake",
])
def test_path_ids_are_refused(running, path):
    srv, study, tokens, _ = running
    before = db_dump(study)
    status, _, _ = raw_request(srv.url, "POST", path, _handshake_body(), {
        "Authorization": f"Bearer {tokens['P01']}", "Content-Type": "application/json"})
    assert 400 <= status < 500
    assert db_dump(study) == before
    _alive(srv)


@pytest.mark.parametrize("path", [
    "/api/v1/participants/P01/files/../server/state.sqlite",
    "/api/v1/participants/P01/files/..%2Fserver%2Fadmin_token",
    "/api/v1/participants/P01/files/videos/../../server/admin_token",
    "/api/v1/participants/P01/files//etc/passwd",
    "/api/v1/participants/P01/files/videos",
])
def test_files_outside_the_list_are_not_served(running, path):
    srv, _, tokens, _ = running
    status, _, body = raw_request(srv.url, "GET", path, headers={
        "Authorization": f"Bearer {tokens['P01']}"})
    assert status == 404 and ADMIN.encode() not in body


@pytest.mark.parametrize("body, headers, status", [
    (b"{" * 10, {}, 400),
    (b"[" * 200_000, {}, 400),
    (b'{"protocol": NaN}', {}, 400),
    (bytes(range(256)) * 10, {}, 400),
    (b"", {}, 400),
    (b"x" * (2 << 20), {}, 413),
    (b"x" * 10, {"Content-Length": str(5 << 20)}, 413),
    (b"1", {"Content-Length": "abc"}, 400),
])
def test_garbage_and_oversized_bodies(running, body, headers, status):
    srv, study, tokens, _ = running
    before = db_dump(study)
    got, _, _ = raw_request(srv.url, "POST", "/api/v1/participants/P02/entries", body, {
        "Authorization": f"Bearer {tokens['P02']}", "Content-Type": "application/json",
        **headers})
    assert got == status
    assert db_dump(study) == before
    _alive(srv)


def test_chunked_body_over_the_limit_is_cut_off(running):
    srv, study, tokens, _ = running
    before = db_dump(study)
    chunk = b"x" * 65536
    chunks = b"".join(b"%x\r\n%s\r\n" % (len(chunk), chunk) for _ in range(40)) + b"0\r\n\r\n"
    got, _, _ = raw_request(srv.url, "POST", "/api/v1/participants/P02/entries", chunks, {
        "Authorization": f"Bearer {tokens['P02']}", "Content-Type": "application/json",
        "Transfer-Encoding": "chunked"})
    assert got == 413
    assert db_dump(study) == before
    _alive(srv)


def test_rate_limit_is_per_token_with_retry_after(running):
    srv, _, tokens, _ = running
    statuses = []
    retry = None
    for _ in range(100):
        status, headers, _ = raw_request(srv.url, "GET", "/api/v1/participants/P03/study",
                                         headers={"Authorization": f"Bearer {tokens['P03']}"})
        statuses.append(status)
        if status == 429:
            retry = headers.get("retry-after")
            break
    assert statuses[0] == 200 and statuses[-1] == 429 and retry and int(retry) >= 1
    # another participant (the same address) is not slowed down
    status, _, _ = raw_request(srv.url, "GET", "/api/v1/participants/P02/study",
                               headers={"Authorization": f"Bearer {tokens['P02']}"})
    assert status == 200


def test_admin_api_and_dashboard_need_the_admin_token(running):
    srv, _, tokens, _ = running
    for path in ("/api/v1/admin/sessions", "/api/v1/admin/participants/P01/entries",
                 "/dashboard"):
        assert raw_request(srv.url, "GET", path)[0] == 401
        assert raw_request(srv.url, "GET", path, headers={
            "Authorization": f"Bearer {tokens['P01']}"})[0] == 403
        assert raw_request(srv.url, "GET", path, headers={
            "Authorization": f"Bearer {ADMIN}"})[0] == 200
    admin = {"Authorization": f"Bearer {ADMIN}"}
    for query in ("limit=-1", "limit=0", "limit=5001", "after=-1", "limit=x"):
        status, _, body = raw_request(
            srv.url, "GET", f"/api/v1/admin/participants/P01/entries?{query}", headers=admin)
        assert status == 400 and b"limit (1..5000)" in body, (query, status)  # -1: no limit
    status, _, page = raw_request(srv.url, "GET", "/dashboard")
    assert status == 401 and b'name="token"' in page  # the page asks for the token
    status, headers, _ = raw_request(
        srv.url, "POST", "/dashboard/login", b"token=wrong",
        {"Content-Type": "application/x-www-form-urlencoded"})
    assert status == 403 and "set-cookie" not in headers
    status, headers, _ = raw_request(
        srv.url, "POST", "/dashboard/login", f"token={ADMIN}".encode(),
        {"Content-Type": "application/x-www-form-urlencoded"})
    assert status == 303 and "httponly" in headers["set-cookie"].lower()
    cookie = headers["set-cookie"].split(";")[0]
    status, headers, page = raw_request(srv.url, "GET", "/dashboard",
                                        headers={"Cookie": cookie})
    assert status == 200 and b"P01" in page
    assert "default-src 'self'" in headers["content-security-policy"]
    forged = cookie.split("=")[0] + "=99999999999.deadbeef"
    assert raw_request(srv.url, "GET", "/dashboard", headers={"Cookie": forged})[0] == 401
    # Logging out ends the login on the server: a copy of the cookie (a shared machine, a
    # synced browser profile) opens nothing afterwards, and a new login works at once.
    form = {"Content-Type": "application/x-www-form-urlencoded"}
    assert raw_request(srv.url, "POST", "/dashboard/logout", b"", {"Cookie": cookie})[0] == 303
    assert raw_request(srv.url, "GET", "/dashboard", headers={"Cookie": cookie})[0] == 401
    assert raw_request(srv.url, "GET", "/api/v1/admin/sessions",
                       headers={"Cookie": cookie})[0] == 401
    status, headers, _ = raw_request(srv.url, "POST", "/dashboard/login",
                                     f"token={ADMIN}".encode(), form)
    again = headers["set-cookie"].split(";")[0]
    assert raw_request(srv.url, "GET", "/dashboard", headers={"Cookie": again})[0] == 200
    # a logout without a valid cookie (a stranger's POST) logs nobody out
    assert raw_request(srv.url, "POST", "/dashboard/logout", b"", {"Cookie": forged})[0] == 303
    assert raw_request(srv.url, "POST", "/dashboard/logout", b"")[0] == 303
    assert raw_request(srv.url, "GET", "/dashboard", headers={"Cookie": again})[0] == 200
