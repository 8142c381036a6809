"""The dashboard in the browser: the page (or the login form), logging in and out with a
cookie, and the figures of the latest statistics. :class:`study_server.dashboard.Pages`
renders the HTML."""

from __future__ import annotations

import math
import time
from urllib.parse import parse_qs

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import HTMLResponse, RedirectResponse, Response

from .. import auth
from ..dashboard import ORDERS
from ..ingest import Refused
from .admin import admin_status
from .common import HTML_HEADERS, SECURITY_HEADERS, error, read_body, server_of

MAX_LOGIN_BYTES = 4096


async def dashboard(request: Request) -> Response:
    """The dashboard for the admin; the login form (401/403) for anyone else."""
    pages = server_of(request).pages
    ok = admin_status(request)
    if ok is None:  # a cookie that no longer opens the page has expired (or was edited)
        expired = auth.COOKIE in request.cookies
        return HTMLResponse(pages.login("Your login has expired; log in again." if expired
                                        else None), status_code=401, headers=HTML_HEADERS)
    if not ok:
        return HTMLResponse(pages.login("That is not the admin token."), status_code=403,
                            headers=HTML_HEADERS)
    order = request.query_params.get("order", "id")
    html = await run_in_threadpool(pages.dashboard, order if order in ORDERS else "id")
    return HTMLResponse(html, headers=HTML_HEADERS)


def _login_key(request: Request) -> str:
    """Login failures are counted per client address (the proxy's forwarded one behind
    ``--behind-proxy``), so a stranger's wrong guesses cannot lock the experimenter out."""
    return "login:" + (request.client.host if request.client is not None else "-")


def _login_page(request: Request, message: str, status: int) -> Response:
    return HTMLResponse(server_of(request).pages.login(message), status_code=status,
                        headers=HTML_HEADERS)


async def login(request: Request) -> Response:
    """The login form's POST: a right token sets the cookie. Wrong tokens are rate-limited
    per client address before the body is read; the body is read bounded (4 KiB)."""
    st = server_of(request)
    key = _login_key(request)
    if (wait := st.login_limiter.wait_time(key)) > 0:
        return _login_page(request, f"Too many wrong tokens from this address; try again in "
                           f"{math.ceil(wait)} s.", 429)
    try:
        body = await read_body(request, MAX_LOGIN_BYTES)
    except Refused as exc:
        return _login_page(request, "Request too large." if exc.status == 413
                           else "Invalid request.", exc.status)
    token = (parse_qs(body.decode("utf-8", "replace")).get("token") or [""])[0].strip()
    if not auth.token_matches(token, auth.token_sha256(st.admin_token)):
        st.login_limiter.acquire(key)
        return _login_page(request, "That is not the admin token.", 403)
    resp = RedirectResponse("/dashboard", status_code=303, headers=SECURITY_HEADERS)
    cookie = auth.make_cookie(st.admin_token, logged_out_ms=st.dashboard_logout_ms)
    resp.set_cookie(auth.COOKIE, cookie,
                    max_age=auth.COOKIE_LIFETIME_S, httponly=True, samesite="strict",
                    secure=st.config.secure_cookies, path="/")
    return resp


async def logout(request: Request) -> Response:
    """Ends every dashboard login made so far, on the server too: a copy of the cookie (a
    shared machine, a backup of the browser profile) opens nothing afterwards. A request
    without a valid cookie only clears its own cookie."""
    st = server_of(request)
    if admin_status(request):
        at_ms = int(time.time() * 1000)
        await run_in_threadpool(st.store.record_dashboard_logout, at_ms)
        st.dashboard_logout_ms = at_ms
    resp = RedirectResponse("/dashboard", status_code=303, headers=SECURITY_HEADERS)
    resp.delete_cookie(auth.COOKIE, path="/", httponly=True, samesite="strict",
                       secure=st.config.secure_cookies)
    return resp


async def figure(request: Request) -> Response:
    """One PNG of the latest statistics snapshot (admin only)."""
    if not admin_status(request):
        return error(401, "log in on /dashboard first")
    png = server_of(request).stats.snapshot().figures.get(request.path_params["name"])
    if png is None:
        return error(404, "no such figure (yet)")
    return Response(png, media_type="image/png", headers=SECURITY_HEADERS)
