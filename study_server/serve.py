"""Running the server: the listening socket, TLS, uvicorn."""

from __future__ import annotations

import ipaddress
import logging
import socket
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from session_store.errors import StudyError

from .config import ServerConfig

log = logging.getLogger(__name__)


@dataclass
class Listen:
    host: str = "127.0.0.1"
    port: int = 8000
    certfile: Path | None = None
    keyfile: Path | None = None
    insecure: bool = False
    """Allow plain HTTP on a non-loopback address (only behind a TLS reverse proxy...)."""
    proxy: str | None = None
    """Addresses of a reverse proxy whose X-Forwarded-For/-Proto headers are trusted."""

    @property
    def tls(self) -> bool:
        return self.certfile is not None


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_listen(listen: Listen) -> None:
    if (listen.certfile is None) != (listen.keyfile is None):
        raise StudyError("give both --certfile and --keyfile for TLS")
    for p in (listen.certfile, listen.keyfile):
        if p is not None and not p.is_file():
            raise StudyError(f"TLS file not found: {p}")
    if not listen.tls and not listen.insecure and not is_loopback(listen.host):
        raise StudyError(
            f"serving on {listen.host} without TLS would send tokens and ratings in clear text: "
            "give --certfile/--keyfile, or serve on 127.0.0.1 behind a TLS reverse proxy (see "
            "the README), or pass --insecure if you really mean it")
    if not 0 <= listen.port <= 65535:
        raise StudyError(f"--port {listen.port} is not a port number")


def bind(listen: Listen) -> socket.socket:
    family = socket.AF_INET6 if ":" in listen.host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((listen.host, listen.port))
    except OSError as exc:
        sock.close()
        raise StudyError(f"cannot listen on {listen.host}:{listen.port} ({exc.strerror}); "
                         "choose another --port or stop what uses it") from None
    sock.listen(2048)
    sock.set_inheritable(True)
    return sock


def serve(config: ServerConfig, listen: Listen,
          on_ready: Callable[[str, str, bool], None] | None = None) -> None:
    """Serve until interrupted. ``on_ready(url, admin_token, token_was_created)`` is called
    once the socket listens (the CLI prints it)."""
    import uvicorn

    from .app import create_app
    from .state import ServerState

    check_listen(listen)
    config.secure_cookies = config.secure_cookies or listen.tls
    state = ServerState.open(config)
    try:
        sock = bind(listen)
    except BaseException:
        state.store.close()
        raise
    port = sock.getsockname()[1]
    scheme = "https" if listen.tls else "http"
    host = f"[{listen.host}]" if ":" in listen.host else listen.host
    url = f"{scheme}://{host}:{port}"
    uv = uvicorn.Config(
        create_app(config, state), log_level="warning", access_log=False,
        ssl_certfile=str(listen.certfile) if listen.certfile else None,
        ssl_keyfile=str(listen.keyfile) if listen.keyfile else None,
        proxy_headers=listen.proxy is not None,
        forwarded_allow_ips=listen.proxy or "127.0.0.1",
        timeout_keep_alive=30, limit_concurrency=2000, server_header=False)
    server = uvicorn.Server(uv)
    if on_ready is not None:
        on_ready(url, state.admin_token, state.admin_token_created)
    try:
        server.run(sockets=[sock])
    finally:
        sock.close()
