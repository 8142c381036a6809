"""One small HTTP client for the study server (standard library only).

Failures are sorted into two kinds the callers act on differently:
:class:`ServerUnavailable` (network down, timeouts, 5xx, 429: queue and try again later, with
the server's ``Retry-After`` when it gives one) and :class:`ServerRefused` (4xx: the request
itself is wrong, e.g. a bad token or a contradiction with acknowledged data; trying again
will not help).
"""

from __future__ import annotations

import json
import logging
import os
import ssl
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from http.client import HTTPException, HTTPResponse
from typing import Any

from session_store.errors import StudyError
from session_store.invite import check_server_url

log = logging.getLogger(__name__)

DEFAULT_TIMEOUT_S = 20.0
USER_AGENT = "cgvq-study"


class ServerUnavailable(StudyError):  # noqa: N818 (a state, not a failure of the caller)
    """The server cannot be reached or asks to come back later; queue and retry."""

    def __init__(self, message: str, retry_after: float | None = None) -> None:
        super().__init__(message)
        self.retry_after = retry_after


class ServerRefused(StudyError):  # noqa: N818
    """The server refused the request (4xx); ``status`` and the server's ``detail``."""

    def __init__(self, message: str, status: int, detail: str = "") -> None:
        super().__init__(message)
        self.status = status
        self.detail = detail


CA_FILE_ENV = "CGVQ_CA_FILE"


def ssl_context() -> ssl.SSLContext:
    """Certifi's CA bundle where it is installed (the frozen app carries it: a bundled Python
    may find no system store), else the system's; ``$CGVQ_CA_FILE`` adds a lab's own CA (a
    server with a self-signed certificate)."""
    try:
        import certifi
    except ImportError:
        ctx = ssl.create_default_context()
    else:
        ctx = ssl.create_default_context(cafile=certifi.where())
    extra = os.environ.get(CA_FILE_ENV)
    if extra:
        try:
            ctx.load_verify_locations(cafile=extra)
        except (OSError, ssl.SSLError) as exc:
            raise StudyError(f"${CA_FILE_ENV}={extra}: not a readable CA certificate file "
                             f"({exc})") from None
    return ctx


def _detail(exc: urllib.error.HTTPError) -> str:
    try:
        raw = exc.read(4096)
    except (OSError, HTTPException):
        return ""
    try:
        data = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        return raw.decode("utf-8", "replace").strip()[:300]
    if isinstance(data, dict) and isinstance(data.get("detail"), str):
        return data["detail"]
    return ""


def _retry_after(exc: urllib.error.HTTPError) -> float | None:
    value = exc.headers.get("Retry-After") if exc.headers else None
    try:
        return max(0.0, float(value)) if value is not None else None
    except ValueError:
        return None


def _origin(url: str) -> tuple[str, str, int | None]:
    parts = urllib.parse.urlsplit(url)
    port = parts.port or {"http": 80, "https": 443}.get(parts.scheme.lower())
    return parts.scheme.lower(), (parts.hostname or "").lower(), port


class SameOriginRedirects(urllib.request.HTTPRedirectHandler):
    """Follows a redirect only within the study server's own origin (scheme, host, port):
    urllib's default copies every header, the bearer token included, to any other host and
    from https to http. The API never redirects elsewhere, so such an answer is refused."""

    def redirect_request(self, req: urllib.request.Request, fp: Any, code: int, msg: str,
                         headers: Any, newurl: str) -> urllib.request.Request | None:
        if _origin(newurl) != _origin(req.full_url):
            fp.close()
            where = "{}://{}:{}".format(*_origin(newurl))
            raise ServerRefused(
                f"the study server redirected to another address ({where}); redirects to "
                "another server are not followed (the token stays here): check the server "
                "address", code)
        return super().redirect_request(req, fp, code, msg, headers, newurl)


def plain_reason(exc: BaseException) -> str:
    """Why a connection failed, in words and without an errno ("connection reset by peer",
    "no answer in time", not "[Errno 104] Connection reset by peer")."""
    reason = getattr(exc, "reason", None)
    if isinstance(reason, BaseException) and reason is not exc:
        return plain_reason(reason)
    if isinstance(exc, TimeoutError) or "timed out" in str(exc):
        return "no answer in time"
    text = getattr(exc, "strerror", None) or (reason if isinstance(reason, str) else None) \
        or str(exc) or type(exc).__name__
    return str(text)[:1].lower() + str(text)[1:]


class ServerClient:
    """Requests to one study server with one bearer token (a participant's or the admin's)."""

    def __init__(self, server: str, token: str, *, timeout: float = DEFAULT_TIMEOUT_S) -> None:
        self.server = check_server_url(server)
        self._token = token
        self.timeout = timeout
        handlers: list[urllib.request.BaseHandler] = [
            urllib.request.HTTPSHandler(context=ssl_context()), SameOriginRedirects()]
        self._opener = urllib.request.build_opener(*handlers)

    def _request(self, method: str, path: str, body: bytes | None = None,
                 headers: dict[str, str] | None = None) -> urllib.request.Request:
        req = urllib.request.Request(self.server + path, data=body, method=method)
        req.add_header("Authorization", f"Bearer {self._token}")
        req.add_header("User-Agent", USER_AGENT)
        for k, v in (headers or {}).items():
            req.add_header(k, v)
        return req

    @contextmanager
    def open(self, method: str, path: str, body: bytes | None = None,
             headers: dict[str, str] | None = None) -> Iterator[HTTPResponse]:
        """The raw response (for streaming downloads); errors sorted as the module says."""
        req = self._request(method, path, body, headers)
        try:
            resp = self._opener.open(req, timeout=self.timeout)
        except urllib.error.HTTPError as exc:
            detail = _detail(exc)
            if exc.code == 429 or exc.code >= 500:
                raise ServerUnavailable(
                    f"the study server answered {exc.code}" + (f": {detail}" if detail else ""),
                    _retry_after(exc)) from None
            raise ServerRefused(
                f"the study server refused the request ({exc.code})"
                + (f": {detail}" if detail else ""), exc.code, detail) from None
        except (urllib.error.URLError, OSError, HTTPException) as exc:
            raise ServerUnavailable(f"cannot reach the study server {self.server} "
                                    f"({plain_reason(exc)})") from None
        try:
            yield resp
        finally:
            resp.close()

    def json(self, method: str, path: str, payload: Any | None = None) -> Any:
        """Send ``payload`` as JSON (when given) and return the decoded JSON answer."""
        body = None
        headers = {"Accept": "application/json"}
        if payload is not None:
            body = json.dumps(payload, separators=(",", ":"), allow_nan=False).encode("utf-8")
            headers["Content-Type"] = "application/json"
        with self.open(method, path, body, headers) as resp:
            try:
                raw = resp.read()
            except (OSError, HTTPException) as exc:
                raise ServerUnavailable(f"the study server's answer was cut off "
                                        f"({plain_reason(exc)})") from None
        try:
            return json.loads(raw)
        except (ValueError, UnicodeDecodeError):
            raise ServerUnavailable("the study server's answer is not JSON (a proxy error "
                                    "page?)") from None
