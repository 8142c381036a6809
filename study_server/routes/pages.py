"""The dashboard in the browser: the page (or the login form), logging in and out with a
cookie, and the figures of the latest statistics. :class:`study_server.dashboard.Pages`
renders the HTML."""

from __future__ import annotations

from urllib.parse import parse_qs

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import HTMLResponse, RedirectResponse, Response

from .. import auth
from .admin import admin_status
from .common import HTML_HEADERS, SECURITY_HEADERS, error, server_of

MAX_LOGIN_BYTES = 4096


async def dashboard(request: Request) -> Response:
    """The dashboard for the admin; the login form (401/403) for anyone else."""
    pages = server_of(request).pages
    ok = admin_status(request)
    if ok is None:
        return HTMLResponse(pages.login(), status_code=401, headers=HTML_HEADERS)
    if not ok:
        return HTMLResponse(pages.login("That is not the admin token."), status_code=403,
                            headers=HTML_HEADERS)
    html = await run_in_threadpool(pages.dashboard)
    return HTMLResponse(html, headers=HTML_HEADERS)


async def login(request: Request) -> Response:
    """The login form's POST: a right token sets the cookie; attempts are rate-limited."""
    st = server_of(request)
    body = await request.body()
    if len(body) > MAX_LOGIN_BYTES:
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
    """One PNG of the latest statistics snapshot (admin only)."""
    if not admin_status(request):
        return error(401, "log in on /dashboard first")
    png = server_of(request).stats.snapshot().figures.get(request.path_params["name"])
    if png is None:
        return error(404, "no such figure (yet)")
    return Response(png, media_type="image/png", headers=SECURITY_HEADERS)
