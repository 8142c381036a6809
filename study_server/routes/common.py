"""What every handler shares: security headers, JSON errors, the bounded JSON body and the
running server of a request; and the two routes of no group (``/`` and ``/healthz``)."""

from __future__ import annotations

import json
import logging
import math
import re
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response

from session_store.sqlite_errors import is_disk_full

from ..ingest import Refused
from ..state import ServerState

log = logging.getLogger(__name__)

SECURITY_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
    "Cache-Control": "no-store",
}
HTML_HEADERS = {**SECURITY_HEADERS, "Content-Security-Policy":
                "default-src 'self'; img-src 'self' data:; style-src 'self'; "
                "script-src 'self'; form-action 'self'; frame-ancestors 'none'"}


def server_of(request: Request) -> ServerState:
    """The running server (set once by :func:`study_server.app.create_app`)."""
    return request.app.state.server


def error(status: int, detail: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"detail": detail}, status_code=status,
                        headers={**SECURITY_HEADERS, **(headers or {})})


async def guarded(work: Callable[[], Awaitable[Response]]) -> Response:
    """``work()``, with a :class:`Refused` turned into its JSON error (and ``Retry-After``)."""
    try:
        return await work()
    except Refused as exc:
        headers = {}
        if exc.retry_after is not None:
            headers["Retry-After"] = str(max(1, math.ceil(exc.retry_after)))
        return error(exc.status, exc.detail, headers)


def _no_constants(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


async def read_body(request: Request, limit: int) -> bytes:
    """The request's body, refused (413) beyond ``limit`` bytes: the declared
    ``Content-Length`` first, then the bytes really sent, counted while they stream in, so
    an oversized body is never held in memory (every route reads its body here)."""
    length = request.headers.get("content-length")
    if length is not None:
        if not re.fullmatch(r"[0-9]{1,18}", length):
            raise Refused(400, "invalid Content-Length")
        if int(length) > limit:
            raise Refused(413, f"request body over {limit} bytes")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise Refused(413, f"request body over {limit} bytes")
        chunks.append(chunk)
    return b"".join(chunks)


async def read_json(request: Request, limit: int) -> Any:
    """The request's JSON body, refused (413) beyond ``limit`` bytes before it is parsed."""
    body = await read_body(request, limit)
    try:
        return json.loads(body, parse_constant=_no_constants)
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise Refused(400, "the request body is not valid JSON") from None


async def health(request: Request) -> Response:
    return JSONResponse({"ok": True, "study_id": server_of(request).study_id},
                        headers=SECURITY_HEADERS)


async def root(request: Request) -> Response:
    return RedirectResponse("/dashboard", status_code=303)


DISK_FULL_RETRY_S = 60


@dataclass
class Every:
    """True at most once per ``seconds``: one log line for a condition that repeats with
    every request (one per application, made by :func:`study_server.app.create_app`)."""

    seconds: float
    _last: float = -math.inf

    def due(self) -> bool:
        now = time.monotonic()
        if now - self._last < self.seconds:
            return False
        self._last = now
        return True


async def on_storage_error(request: Request, exc: Exception) -> Response:
    """A full disk is not a bug: every request would log a traceback while participants' apps
    retry. It is logged in one line a minute and answered 503 with ``Retry-After``; nothing
    was stored, and the uploads go through once space is freed, without a restart. Any other
    storage error goes on to :func:`on_error` (handled here, a response is final: Starlette
    re-raises what reaches ``on_error`` so that the ASGI server logs it a second time)."""
    if not is_disk_full(exc):
        raise exc
    if request.app.state.disk_full_log.due():
        log.error("the disk of the study folder is full (%s): requests that write are "
                  "answered 503 and retried by the participants' apps; free space, "
                  "no restart is needed", exc)
    return error(503, "the server's disk is full; try again later",
                 {"Retry-After": str(DISK_FULL_RETRY_S)})


async def on_error(request: Request, exc: Exception) -> Response:
    """Any unexpected exception: logged with its traceback, answered with a bare 500."""
    log.exception("unexpected error on %s", request.url.path)
    return error(500, "internal server error")
