"""The study server's ASGI application (Starlette): the routes and what runs around them.

The handlers live in :mod:`study_server.routes`, one module per group (participant API, admin
API, dashboard pages); each reads the running server from ``request.app.state.server``.
Blocking work (SQLite, hashing) runs in the thread pool so one slow request never stalls the
others.
"""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import AsyncIterator
from pathlib import Path

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.routing import BaseRoute, Mount, Route
from starlette.staticfiles import StaticFiles

from .config import ServerConfig
from .routes import admin, common, pages, participants
from .state import ServerState

HERE = Path(__file__).parent


def routes() -> list[BaseRoute]:
    """Every URL the server answers, with its handler."""
    api = participants.PREFIX
    return [
        Route("/", common.root),
        Route("/healthz", common.health),
        Route(f"{api}/study", participants.study),
        Route(f"{api}/files/{{path:path}}", participants.files),
        Route(f"{api}/handshake", participants.handshake, methods=["POST"]),
        Route(f"{api}/entries", participants.entries, methods=["POST"]),
        Route(f"{api}/block", participants.block, methods=["POST"]),
        Route("/api/v1/admin/sessions", admin.sessions),
        Route("/api/v1/admin/participants/{pid}/entries", admin.participant_entries),
        Route("/api/v1/admin/manifests/{sha}", admin.version_manifest),
        Route("/dashboard", pages.dashboard),
        Route("/dashboard/login", pages.login, methods=["POST"]),
        Route("/dashboard/logout", pages.logout, methods=["POST"]),
        Route("/dashboard/figures/{name}.png", pages.figure),
        Mount("/dashboard/static", StaticFiles(directory=HERE / "static"), name="static"),
    ]


@contextlib.asynccontextmanager
async def lifespan(app: Starlette) -> AsyncIterator[None]:
    """Starts the server state's background work with the app and closes it on shutdown."""
    st: ServerState = app.state.server
    st.start()
    try:
        yield
    finally:
        await run_in_threadpool(st.stop)


def create_app(config: ServerConfig, state: ServerState | None = None) -> Starlette:
    """The application over one study folder (``state`` prepared by the caller or here)."""
    app = Starlette(routes=routes(), lifespan=lifespan,
                    exception_handlers={sqlite3.Error: common.on_storage_error,
                                        OSError: common.on_storage_error,
                                        Exception: common.on_error})
    app.state.server = state or ServerState.open(config)
    app.state.disk_full_log = common.Every(common.DISK_FULL_RETRY_S)
    return app
