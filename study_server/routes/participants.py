"""The participant API (:mod:`session_store.protocol`): the study listing, its files, the
handshake and the uploads.

Each request is checked, in this order, for the participant id (no path characters), the
token (401 without, 403 wrong, 410 withdrawn) and the per-token rate limit (429 with
``Retry-After``); uploads then for the body size (``Content-Length`` and the bytes really
sent) and the JSON. Only then does :class:`~study_server.ingest.Ingest` look at the content,
so nothing is written for a request refused before that point.
"""

from __future__ import annotations

from functools import partial
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, StrictStr
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response

from session_store.errors import StudyError
from session_store.ids import check_participant_id
from session_store.protocol import PROTOCOL

from .. import auth
from ..ingest import Refused, SessionId, parse
from .common import SECURITY_HEADERS, guarded, read_json, server_of

PREFIX = "/api/v1/participants/{pid}"


def client_address(request: Request) -> str | None:
    """The client's address, kept only where the study asks for it (``store_addresses``)."""
    if not server_of(request).config.store_addresses or request.client is None:
        return None
    return request.client.host


def participant_of(request: Request, *, starting: bool = False) -> str:
    """The participant id of the path, once id, token and rate limit pass (blocking: SQLite);
    ``starting`` (fetching the study) also needs the study to be open."""
    st = server_of(request)
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
    if starting:
        st.check_open(pid)
    return pid


def _seen(request: Request, pid: str) -> None:
    """A download is contact: the dashboard shows who fetched the study (and when last),
    before their session file exists (a download stuck halfway, a failed pre-flight)."""
    server_of(request).store.touch(pid, _now(), client_address(request))


def _now() -> str:
    from session_store.records import utc_now

    return utc_now()


async def study(request: Request) -> Response:
    """The file list of the study version the participant's session is pinned to (fetching
    it is starting: refused once a study closed at its target)."""
    async def work() -> Response:
        pid = await run_in_threadpool(partial(participant_of, request, starting=True))
        await run_in_threadpool(_seen, request, pid)
        version = await run_in_threadpool(server_of(request).version_for, pid)
        return JSONResponse(version.listing(), headers=SECURITY_HEADERS)
    return await guarded(work)


async def files(request: Request) -> Response:
    """One file of the participant's study version (the manifest from the database)."""
    async def work() -> Response:
        pid = await run_in_threadpool(participant_of, request)
        await run_in_threadpool(_seen, request, pid)
        version = await run_in_threadpool(server_of(request).version_for, pid)
        f = version.by_path().get(request.path_params["path"])
        if f is None:
            raise Refused(404, "no such file in this study")
        if f.local is None:
            return Response(version.manifest_bytes, media_type="application/json",
                            headers=SECURITY_HEADERS)
        return FileResponse(f.local, headers=SECURITY_HEADERS,
                            media_type="application/octet-stream")
    return await guarded(work)


async def handshake(request: Request) -> Response:
    async def work() -> Response:
        st = server_of(request)
        pid = await run_in_threadpool(participant_of, request)
        data = await read_json(request, st.config.max_body_bytes)
        answer = await run_in_threadpool(st.ingest.handshake, pid, data,
                                         client_address(request))
        return JSONResponse(answer, headers=SECURITY_HEADERS)
    return await guarded(work)


class BlockIn(BaseModel):
    """A request for the next block of an adaptive study (:mod:`study_server.allocator`)."""

    model_config = ConfigDict(extra="forbid")
    protocol: Literal[PROTOCOL]  # type: ignore[valid-type]
    session_id: SessionId
    block: Annotated[StrictInt, Field(ge=2, le=1000)]
    last: Annotated[StrictStr, Field(max_length=200)] | None = None


async def block(request: Request) -> Response:
    """The next block of trials of the participant's session (adaptive allocation); the
    same block again when it was issued before."""
    async def work() -> Response:
        st = server_of(request)
        pid = await run_in_threadpool(participant_of, request)
        msg: BlockIn = parse(BlockIn, await read_json(request, st.config.max_body_bytes))
        alloc = await run_in_threadpool(st.allocator_of, pid)
        issued = await run_in_threadpool(alloc.issue, pid, msg.session_id, msg.block,
                                         msg.last)
        return JSONResponse(issued.answer(), headers=SECURITY_HEADERS)
    return await guarded(work)


async def entries(request: Request) -> Response:
    """New outbox entries; the statistics worker is woken after each accepted upload."""
    async def work() -> Response:
        st = server_of(request)
        pid = await run_in_threadpool(participant_of, request)
        data = await read_json(request, st.config.max_body_bytes)
        answer = await run_in_threadpool(st.ingest.upload, pid, data, client_address(request))
        st.stats.poke()
        (await run_in_threadpool(st.allocator_of, pid)).poke()
        return JSONResponse(answer, headers=SECURITY_HEADERS)
    return await guarded(work)
