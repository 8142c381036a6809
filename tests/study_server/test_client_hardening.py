"""The participant's and experimenter's client against a hostile or misconfigured server:
no token sent to another origin on a redirect, no listed file path that leaves the study
folder on any OS (Windows drive letters included)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from session_store.errors import StudyError
from study_app.remote import ServerClient, ServerRefused
from study_app.remote.download import DownloadPlan, RemoteFile, _remote_file, _safe_relative

TOKEN = "secret-token-0123456789abcdef"


@contextmanager
def http_server(answer) -> Iterator[tuple[str, list[tuple[str, str | None]]]]:
    """A server on 127.0.0.1 (free port) that answers with ``answer(path)`` -> (status,
    headers, body) and records (path, Authorization) of each request."""
    seen: list[tuple[str, str | None]] = []

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            seen.append((self.path, self.headers.get("Authorization")))
            status, headers, body = answer(self.path)
            self.send_response(status)
            for k, v in {**headers, "Content-Length": str(len(body))}.items():
                self.send_header(k, v)
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args) -> None:
            pass

    srv = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05},
                              daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{srv.server_address[1]}", seen
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(10)


def _json(_path: str) -> tuple[int, dict, bytes]:
    return 200, {"Content-Type": "application/json"}, b'{"ok": true}'


@pytest.mark.parametrize("host", ["localhost", "127.0.0.1"])
def test_a_redirect_to_another_origin_is_refused_and_gets_no_token(host):
    with http_server(_json) as (other, other_seen):
        port = other.rsplit(":", 1)[1]

        def redirect(path: str) -> tuple[int, dict, bytes]:
            return 302, {"Location": f"http://{host}:{port}{path}"}, b""

        with http_server(redirect) as (url, seen):
            client = ServerClient(url, TOKEN)
            with pytest.raises(ServerRefused) as exc:
                client.json("GET", "/api/v1/admin/sessions")
    assert "redirected to another address" in str(exc.value)
    assert seen == [("/api/v1/admin/sessions", f"Bearer {TOKEN}")]
    assert other_seen == []  # the other origin never saw the token (nor the request)


def test_a_redirect_within_the_server_is_followed():
    def answer(path: str) -> tuple[int, dict, bytes]:
        return (302, {"Location": "/moved"}, b"") if path == "/start" else _json(path)

    with http_server(answer) as (url, seen):
        assert ServerClient(url, TOKEN).json("GET", "/start") == {"ok": True}
    assert [p for p, _ in seen] == ["/start", "/moved"]


@pytest.mark.parametrize("path", [
    "D:/Users/Public/evil.bat", "videos/D:/Users/Public/x.dll", "C:evil.bat", "d:",
    "//server/share/x", "/etc/passwd", "../x", "videos/../../x", "a/./b", "a//b",
    "videos\\..\\x", "CON", "videos/nul.txt", "videos/com1.mkv", "trailing.", "space ",
    "bad|name", "q?.mkv", "nul\0byte", "",
])
def test_paths_that_could_leave_the_folder_on_any_os_are_refused(path):
    with pytest.raises(StudyError):
        _safe_relative(path)


@pytest.mark.parametrize("path", ["manifest.json", "videos/ref0.mkv", "videos/My Scene 01.mkv",
                                  "texts/briefing.de.md", "videos/scène_é.mp4", "conte.mkv"])
def test_ordinary_study_paths_are_kept(path, tmp_path: Path):
    assert _safe_relative(path) == path
    plan = DownloadPlan("s", "0" * 64, (), tmp_path)
    assert plan.local(RemoteFile(path, 1, "0" * 64)).is_relative_to(tmp_path)


@pytest.mark.parametrize("entry", [
    {"path": "a.mkv", "size": -1, "sha256": "0" * 64},
    {"path": "a.mkv", "size": 1, "sha256": "xyz"},
    {"path": "a.mkv", "size": 1, "sha256": "0" * 63},
])
def test_listed_sizes_and_hashes_must_be_valid(entry):
    with pytest.raises(StudyError):
        _remote_file(entry)
