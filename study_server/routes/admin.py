"""The experimenter's API (sessions, a session's entries) and the admin check the dashboard
shares: the admin token as ``Authorization: Bearer`` or the dashboard's login cookie."""

from __future__ import annotations

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import JSONResponse, Response

from session_store.errors import StudyError
from session_store.ids import check_participant_id

from .. import auth
from ..ingest import Refused
from .common import SECURITY_HEADERS, guarded, server_of

MAX_ENTRIES_PER_PAGE = 5000


def admin_status(request: Request) -> bool | None:
    """True: the admin; False: wrong credentials; None: none given."""
    st = server_of(request)
    token = auth.bearer(request.headers.get("authorization"))
    if token is not None:
        return auth.token_matches(token, auth.token_sha256(st.admin_token))
    if auth.cookie_valid(st.admin_token, request.cookies.get(auth.COOKIE),
                         logged_out_ms=st.dashboard_logout_ms):
        return True
    return None


def require_admin(request: Request) -> None:
    ok = admin_status(request)
    if ok is None:
        raise Refused(401, "the admin token is required (Authorization: Bearer ...)")
    if not ok:
        raise Refused(403, "wrong admin token")


async def sessions(request: Request) -> Response:
    """Every invited participant with their session, flags and study version."""
    async def work() -> Response:
        require_admin(request)
        return JSONResponse(await run_in_threadpool(server_of(request).sessions_listing),
                            headers=SECURITY_HEADERS)
    return await guarded(work)


async def participant_entries(request: Request) -> Response:
    """One page of a participant's received entries (``after`` a seq, at most ``limit``)."""
    async def work() -> Response:
        require_admin(request)
        pid = request.path_params["pid"]
        try:
            check_participant_id(pid)
            after = int(request.query_params.get("after", "0"))
            limit = int(request.query_params.get("limit", "1000"))
            if after < 0 or not 1 <= limit <= MAX_ENTRIES_PER_PAGE:
                raise ValueError  # SQLite reads LIMIT -1 as no limit at all
        except (StudyError, ValueError):
            raise Refused(400, f"invalid participant id, after (>= 0) or limit (1.."
                          f"{MAX_ENTRIES_PER_PAGE})") from None
        answer = await run_in_threadpool(server_of(request).entries_listing, pid, after, limit)
        if answer is None:
            raise Refused(404, f"no session of {pid} on the server")
        return JSONResponse(answer, headers=SECURITY_HEADERS)
    return await guarded(work)


async def version_manifest(request: Request) -> Response:
    """The manifest of one served version, byte for byte as registered: sessions run on an
    earlier version are analysed with it (``cgvq-study pull`` saves it beside them)."""
    async def work() -> Response:
        require_admin(request)
        sha = request.path_params["sha"]
        if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise Refused(400, "a manifest version is its sha256 (64 lowercase hex digits)")
        raw = await run_in_threadpool(server_of(request).store.version_manifest, sha)
        if raw is None:
            raise Refused(404, f"no manifest version {sha[:12]}... on the server")
        return JSONResponse({"manifest_sha256": sha, "text": raw.decode("utf-8")},
                            headers=SECURITY_HEADERS)
    return await guarded(work)
