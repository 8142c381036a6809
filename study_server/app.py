"""The study server's ASGI application (Starlette).

Participant endpoints (see :mod:`session_store.protocol`) check, in this order, the
participant id (no path characters), the body size (``Content-Length`` and the bytes really
sent), the token (401 without, 403 wrong, 410 withdrawn), the per-token rate limit (429 with
``Retry-After``) and the JSON; only then does :class:`~.ingest.Ingest` look at the content.
Nothing is written for a request refused before that point. Blocking work (SQLite, hashing)
runs in the thread pool so one slow request never stalls the others.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import (
    FileResponse,
    HTMLResponse,
    JSONResponse,
    RedirectResponse,
    Response,
)
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from session_store.errors import StudyError
from session_store.ids import check_participant_id

from . import auth
from .config import ServerConfig
from .ingest import Refused
from .state import ServerState

log = logging.getLogger(__name__)

HERE = Path(__file__).parent
SECURITY_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
    "Cache-Control": "no-store",
}
HTML_HEADERS = {**SECURITY_HEADERS, "Content-Security-Policy":
                "default-src 'self'; img-src 'self' data:; style-src 'self'; "
                "script-src 'self'; form-action 'self'; frame-ancestors 'none'"}


def _error(status: int, detail: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"detail": detail}, status_code=status,
                        headers={**SECURITY_HEADERS, **(headers or {})})


def _no_constants(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


async def read_json(request: Request, limit: int) -> Any:
    """The request's JSON body, refused (413) beyond ``limit`` bytes before it is parsed."""
    length = request.headers.get("content-length")
    if length is not None:
        if not length.isdigit():
            raise Refused(400, "invalid Content-Length")
        if int(length) > limit:
            raise Refused(413, f"request body over {limit} bytes")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise Refused(413, f"request body over {limit} bytes")
        chunks.append(chunk)
    try:
        return json.loads(b"".join(chunks), parse_constant=_no_constants)
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise Refused(400, "the request body is not valid JSON") from None




def create_app(config: ServerConfig, state: ServerState | None = None) -> Starlette:
    """The application over one study folder (``state`` prepared by the caller or here)."""
    st = state or ServerState.open(config)

    def _address(request: Request) -> str | None:
        if not st.config.store_addresses or request.client is None:
            return None
        return request.client.host

    def participant_of(request: Request) -> str:
        pid = request.path_params["pid"]
        try:
            check_participant_id(pid)
        except StudyError:
            raise Refused(400, "invalid participant id") from None
        token = auth.bearer(request.headers.get("authorization"))
        if token is None:
            raise Refused(401, "a participant token is required (Authorization: Bearer ...)")
        st.check_participant(pid, token)
        wait = st.limiter.acquire(pid)
        if wait > 0:
            raise Refused(429, f"too many requests; try again in {wait:.1f} s", wait)
        return pid

    async def guarded(request: Request, work: Any) -> Response:
        try:
            return await work()
        except Refused as exc:
            headers = {}
            if exc.retry_after is not None:
                headers["Retry-After"] = str(max(1, math.ceil(exc.retry_after)))
            return _error(exc.status, exc.detail, headers)

    # -- participants -----------------------------------------------------------------
    async def study(request: Request) -> Response:
        async def work() -> Response:
            pid = await run_in_threadpool(participant_of, request)
            version = await run_in_threadpool(st.version_for, pid)
            return JSONResponse(version.listing(), headers=SECURITY_HEADERS)
        return await guarded(request, work)

    async def files(request: Request) -> Response:
        async def work() -> Response:
            pid = await run_in_threadpool(participant_of, request)
            version = await run_in_threadpool(st.version_for, pid)
            f = version.by_path().get(request.path_params["path"])
            if f is None:
                raise Refused(404, "no such file in this study")
            if f.local is None:
                return Response(version.manifest_bytes, media_type="application/json",
                                headers=SECURITY_HEADERS)
            return FileResponse(f.local, headers=SECURITY_HEADERS,
                                media_type="application/octet-stream")
        return await guarded(request, work)

    async def handshake(request: Request) -> Response:
        async def work() -> Response:
            pid = await run_in_threadpool(participant_of, request)
            data = await read_json(request, st.config.max_body_bytes)
            answer = await run_in_threadpool(st.ingest.handshake, pid, data, _address(request))
            return JSONResponse(answer, headers=SECURITY_HEADERS)
        return await guarded(request, work)

    async def entries(request: Request) -> Response:
        async def work() -> Response:
            pid = await run_in_threadpool(participant_of, request)
            data = await read_json(request, st.config.max_body_bytes)
            answer = await run_in_threadpool(st.ingest.upload, pid, data, _address(request))
            st.stats.poke()
            return JSONResponse(answer, headers=SECURITY_HEADERS)
        return await guarded(request, work)

    # -- the experimenter -------------------------------------------------------------
    def admin_status(request: Request) -> bool | None:
        """True: the admin; False: wrong credentials; None: none given."""
        token = auth.bearer(request.headers.get("authorization"))
        if token is not None:
            return auth.token_matches(token, auth.token_sha256(st.admin_token))
        if auth.cookie_valid(st.admin_token, request.cookies.get(auth.COOKIE)):
            return True
        return None

    def require_admin(request: Request) -> None:
        ok = admin_status(request)
        if ok is None:
            raise Refused(401, "the admin token is required (Authorization: Bearer ...)")
        if not ok:
            raise Refused(403, "wrong admin token")

    async def admin_sessions(request: Request) -> Response:
        async def work() -> Response:
            require_admin(request)
            return JSONResponse(await run_in_threadpool(st.sessions_listing),
                                headers=SECURITY_HEADERS)
        return await guarded(request, work)

    async def admin_entries(request: Request) -> Response:
        async def work() -> Response:
            require_admin(request)
            pid = request.path_params["pid"]
            try:
                check_participant_id(pid)
                after = int(request.query_params.get("after", "0"))
                limit = min(int(request.query_params.get("limit", "1000")), 5000)
            except (StudyError, ValueError):
                raise Refused(400, "invalid participant id, after or limit") from None
            answer = await run_in_threadpool(st.entries_listing, pid, after, limit)
            if answer is None:
                raise Refused(404, f"no session of {pid} on the server")
            return JSONResponse(answer, headers=SECURITY_HEADERS)
        return await guarded(request, work)

    async def dashboard(request: Request) -> Response:
        ok = admin_status(request)
        if ok is None:
            return HTMLResponse(st.pages.login(), status_code=401, headers=HTML_HEADERS)
        if not ok:
            return HTMLResponse(st.pages.login("That is not the admin token."), status_code=403,
                                headers=HTML_HEADERS)
        html = await run_in_threadpool(st.pages.dashboard)
        return HTMLResponse(html, headers=HTML_HEADERS)

    async def login(request: Request) -> Response:
        body = await request.body()
        if len(body) > 4096:
            return HTMLResponse(st.pages.login("Request too large."), status_code=413,
                                headers=HTML_HEADERS)
        if st.login_limiter.acquire("login") > 0:
            return HTMLResponse(st.pages.login("Too many attempts; wait a minute."),
                                status_code=429, headers=HTML_HEADERS)
        token = (parse_qs(body.decode("utf-8", "replace")).get("token") or [""])[0].strip()
        if not auth.token_matches(token, auth.token_sha256(st.admin_token)):
            return HTMLResponse(st.pages.login("That is not the admin token."),
                                status_code=403, headers=HTML_HEADERS)
        resp = RedirectResponse("/dashboard", status_code=303, headers=SECURITY_HEADERS)
        resp.set_cookie(auth.COOKIE, auth.make_cookie(st.admin_token),
                        max_age=auth.COOKIE_LIFETIME_S, httponly=True, samesite="strict",
                        secure=st.config.secure_cookies, path="/")
        return resp

    async def logout(request: Request) -> Response:
        resp = RedirectResponse("/dashboard", status_code=303, headers=SECURITY_HEADERS)
        resp.delete_cookie(auth.COOKIE, path="/")
        return resp

    async def figure(request: Request) -> Response:
        if not admin_status(request):
            return _error(401, "log in on /dashboard first")
        png = st.stats.snapshot().figures.get(request.path_params["name"])
        if png is None:
            return _error(404, "no such figure (yet)")
        return Response(png, media_type="image/png", headers=SECURITY_HEADERS)

    async def health(request: Request) -> Response:
        return JSONResponse({"ok": True, "study_id": st.study_id}, headers=SECURITY_HEADERS)

    async def root(request: Request) -> Response:
        return RedirectResponse("/dashboard", status_code=303)

    async def on_error(request: Request, exc: Exception) -> Response:
        log.exception("unexpected error on %s", request.url.path)
        return _error(500, "internal server error")

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        st.start()
        try:
            yield
        finally:
            await run_in_threadpool(st.stop)

    api = "/api/v1/participants/{pid}"
    routes = [
        Route("/", root),
        Route("/healthz", health),
        Route(f"{api}/study", study),
        Route(f"{api}/files/{{path:path}}", files),
        Route(f"{api}/handshake", handshake, methods=["POST"]),
        Route(f"{api}/entries", entries, methods=["POST"]),
        Route("/api/v1/admin/sessions", admin_sessions),
        Route("/api/v1/admin/participants/{pid}/entries", admin_entries),
        Route("/dashboard", dashboard),
        Route("/dashboard/login", login, methods=["POST"]),
        Route("/dashboard/logout", logout, methods=["POST"]),
        Route("/dashboard/figures/{name}.png", figure),
        Mount("/dashboard/static", StaticFiles(directory=HERE / "static"), name="static"),
    ]
    return Starlette(routes=routes, lifespan=lifespan,
                     exception_handlers={Exception: on_error})
