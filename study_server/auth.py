"""Tokens: participants' (only their sha256 is stored) and the experimenter's admin token.

The admin token comes from ``$CGVQ_ADMIN_TOKEN`` or is generated once and kept in
``<study>/server/admin_token`` (mode 0600). The dashboard asks for it once and then keeps a
session cookie: its issue time (ms) signed with an HMAC keyed by the admin token, so it
survives a restart, dies when the token changes or after :data:`COOKIE_LIFETIME_S`, and dies
when anyone logs out: the server keeps the time of the last logout, and a cookie issued before
it opens nothing (a copied cookie included).
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
import secrets
import time
from pathlib import Path

from session_store.errors import StudyError

ADMIN_ENV = "CGVQ_ADMIN_TOKEN"
ADMIN_FILE = "admin_token"
COOKIE = "cgvq_admin"
COOKIE_LIFETIME_S = 12 * 3600


def command_line_token(nbytes: int) -> str:
    """``nbytes`` random bytes, URL-safe, never starting with ``-``: a token is typed after
    ``--token`` / ``--admin-token``, where a leading dash would read as another option."""
    while (token := secrets.token_urlsafe(nbytes)).startswith("-"):
        pass
    return token


def new_token() -> str:
    """A participant token: 192 random bits, URL-safe (32 characters)."""
    return command_line_token(24)


def token_sha256(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def token_matches(token: str, stored_sha256: str) -> bool:
    return hmac.compare_digest(token_sha256(token), stored_sha256)


def admin_token(server_dir: Path, *, create: bool = True) -> tuple[str, bool]:
    """(the admin token, whether it was generated just now)."""
    env = os.environ.get(ADMIN_ENV, "").strip()
    if env:
        if len(env) < 16:
            raise StudyError(f"${ADMIN_ENV} is too short: use at least 16 random characters")
        return env, False
    path = server_dir / ADMIN_FILE
    if path.is_file():
        token = path.read_text(encoding="ascii").strip()
        if len(token) >= 16:
            return token, False
    if not create:
        raise StudyError(f"no admin token: set ${ADMIN_ENV} or run 'cgvq-study serve' once")
    server_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    token = command_line_token(32)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="ascii") as fh:
        fh.write(token + "\n")
    os.chmod(path, 0o600)
    return token, True


def bearer(header: str | None) -> str | None:
    """The token of an ``Authorization: Bearer <token>`` header, or None."""
    if not header:
        return None
    scheme, _, value = header.partition(" ")
    if scheme.lower() != "bearer" or not value.strip():
        return None
    return value.strip()


def _signature(admin: str, issued_ms: str) -> str:
    return hmac.new(admin.encode(), f"dashboard:{issued_ms}".encode(),
                    hashlib.sha256).hexdigest()


def make_cookie(admin: str, now: float | None = None, logged_out_ms: int = 0) -> str:
    """A cookie issued now, and after the last logout even within its millisecond."""
    now_ms = int((time.time() if now is None else now) * 1000)
    issued_ms = str(max(now_ms, logged_out_ms + 1))
    return f"{issued_ms}.{_signature(admin, issued_ms)}"


def cookie_valid(admin: str, value: str | None, now: float | None = None,
                 logged_out_ms: int = 0) -> bool:
    """A cookie this server signed, younger than its lifetime and issued after the last
    logout (``logged_out_ms``, epoch ms)."""
    if not value:
        return False
    issued, _, sig = value.partition(".")
    # ASCII digits only: str.isdigit() accepts '²', which int() refuses (a 500 before)
    if not re.fullmatch(r"[0-9]{1,15}", issued):
        return False
    now_ms = (time.time() if now is None else now) * 1000
    if int(issued) <= logged_out_ms or int(issued) + COOKIE_LIFETIME_S * 1000 < now_ms:
        return False
    # as bytes: compare_digest raises on non-ASCII str (a cookie is client-chosen)
    return hmac.compare_digest(_signature(admin, issued).encode(),
                               sig.encode("utf-8", "replace"))
