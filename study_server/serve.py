"""Running the server: the listening socket, TLS, uvicorn."""

from __future__ import annotations

import base64
import errno
import ipaddress
import logging
import re
import shutil
import socket
import ssl
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from session_store.errors import StudyError

from .config import ServerConfig

if TYPE_CHECKING:
    from session_store.run_lock import RunLock

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
    """Refuse listening options that cannot work (one-line StudyErrors), before anything is
    created or announced: the TLS files are loaded and the host is resolved here."""
    if (listen.certfile is None) != (listen.keyfile is None):
        raise StudyError("give both --certfile and --keyfile for TLS")
    for flag, p in (("--certfile", listen.certfile), ("--keyfile", listen.keyfile)):
        if p is not None and not p.is_file():
            raise StudyError(f"{flag}: TLS file not found: {p}")
    if not listen.tls and not listen.insecure and not is_loopback(listen.host):
        raise StudyError(
            f"serving on {listen.host} without TLS would send tokens and ratings in clear text: "
            "give --certfile/--keyfile, or serve on 127.0.0.1 behind a TLS reverse proxy (see "
            "the README), or pass --insecure if you really mean it")
    if listen.insecure and (listen.tls or is_loopback(listen.host)):
        raise StudyError("--insecure allows plain HTTP on a host other than this machine; "
                         f"{'with TLS' if listen.tls else f'on {listen.host}'} it changes "
                         "nothing: drop it")
    if not 0 <= listen.port <= 65535:
        raise StudyError(f"--port {listen.port} is not a port number")
    if listen.proxy is not None:
        listen.proxy = check_proxy_addresses(listen.proxy)
    if listen.certfile is not None and listen.keyfile is not None:
        check_tls_files(listen.certfile, listen.keyfile)
    resolve_host(listen.host, listen.port)


def check_proxy_addresses(text: str) -> str:
    """``--behind-proxy``: comma-separated IP addresses or networks (or ``*``); returns them
    normalised (``a,b``)."""
    items = [t.strip() for t in text.split(",")]
    if not text.strip() or any(not t for t in items):
        raise StudyError(f"--behind-proxy {text!r}: give comma-separated proxy IP addresses, "
                         "e.g. 127.0.0.1 or 10.0.0.5,10.0.0.6 (no empty entries)")
    for item in items:
        if item == "*":
            continue
        try:
            ipaddress.ip_network(item, strict=False)
        except ValueError:
            raise StudyError(f"--behind-proxy: {item!r} is not an IP address or network; give "
                             "the reverse proxy's address, e.g. 127.0.0.1") from None
    return ",".join(items)


_PEM_CERT = re.compile(
    rb"-----BEGIN CERTIFICATE-----\s+([A-Za-z0-9+/=\s]+?)-----END CERTIFICATE-----")
_PEM_KEY = re.compile(rb"-----BEGIN ((?:RSA |EC |ENCRYPTED )?PRIVATE KEY)-----")


def check_tls_files(certfile: Path, keyfile: Path) -> None:
    """Load the certificate and key as the server will; say which file is wrong."""
    cert_bytes = certfile.read_bytes()
    m = _PEM_CERT.search(cert_bytes)
    try:
        valid_cert = m is not None and bool(base64.b64decode(b"".join(m.group(1).split()),
                                                             validate=True))
    except ValueError:
        valid_cert = False
    if not valid_cert:
        raise StudyError(f"--certfile {certfile} is not a PEM certificate (-----BEGIN "
                         "CERTIFICATE-----); give the server's certificate in PEM format")
    key = _PEM_KEY.search(keyfile.read_bytes())
    if key is None:
        raise StudyError(f"--keyfile {keyfile} is not a PEM private key (-----BEGIN PRIVATE "
                         "KEY-----); give the certificate's private key in PEM format")
    if key.group(1) == b"ENCRYPTED PRIVATE KEY":
        raise StudyError(f"--keyfile {keyfile} is encrypted with a passphrase; give an "
                         "unencrypted key (e.g. openssl pkey -in KEY -out plain.key)")

    def no_passphrase() -> bytes:
        raise StudyError(f"--keyfile {keyfile} is encrypted with a passphrase; give an "
                         "unencrypted key")

    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    try:
        ctx.load_verify_locations(cafile=str(certfile))  # parses every certificate in it
    except ssl.SSLError as exc:
        raise StudyError(f"--certfile {certfile} is not a valid PEM certificate "
                         f"({exc.reason or exc}); give the server's certificate in PEM "
                         "format") from None
    try:
        ctx.load_cert_chain(str(certfile), str(keyfile), password=no_passphrase)
    except ssl.SSLError as exc:
        detail = exc.reason or exc.strerror or str(exc)
        if "KEY_VALUES_MISMATCH" in str(exc) or "key values mismatch" in str(exc).lower():
            raise StudyError(f"--keyfile {keyfile} is not the private key of the certificate "
                             f"in --certfile {certfile}") from None
        raise StudyError(f"--keyfile {keyfile} is not a valid PEM private key for --certfile "
                         f"{certfile} ({detail}); give the certificate's unencrypted private "
                         "key in PEM format") from None


_HOST_NAME = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?")


def resolve_host(host: str, port: int) -> None:
    """Refuse a --host that is no address and no resolvable name. A name that cannot be one
    (spaces, punctuation) is refused here, without asking a name server."""
    try:
        ipaddress.ip_address(host)
        return
    except ValueError:
        pass
    if not _HOST_NAME.fullmatch(host):
        raise StudyError(f"--host {host!r} cannot be resolved: it is neither an IP address nor "
                         "a host name (letters, digits, '-' and '.'); give an IP address of "
                         "this machine (e.g. 127.0.0.1 or 0.0.0.0) or its host name")
    try:
        socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise StudyError(f"--host {host!r} cannot be resolved ({reason}); give an IP address "
                         "of this machine (e.g. 127.0.0.1 or 0.0.0.0) or its host name") from None


def bind(listen: Listen) -> socket.socket:
    family = socket.AF_INET6 if ":" in listen.host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((listen.host, listen.port))
    except (OSError, UnicodeError) as exc:
        sock.close()
        code = getattr(exc, "errno", None)
        reason = getattr(exc, "strerror", None) or str(exc)
        where = f"{listen.host}:{listen.port}"
        if code == errno.EADDRINUSE:
            hint = "choose another --port or stop what uses it"
        elif code == errno.EACCES:
            hint = "ports below 1024 need privileges: choose a --port of 1024 or more"
        elif code == errno.EADDRNOTAVAIL:
            hint = (f"--host {listen.host} is not an address of this machine; give one of its "
                    "addresses, 127.0.0.1 or 0.0.0.0")
        else:
            hint = f"--host {listen.host!r} cannot be bound; give an address of this machine"
        raise StudyError(f"cannot listen on {where} ({reason}); {hint}") from None
    sock.listen(2048)
    sock.set_inheritable(True)
    return sock


def _one_server(config: ServerConfig) -> tuple[RunLock | None, Path | None]:
    """The lock of the study's server folder for this process's life, and the folder when
    this call made it. A second server on the same study (a forgotten one, or
    ``--new-version`` beside the old) would hand out two versions and run two allocators on
    one database. No lock where there is no study folder: opening the state says why."""
    from session_store.run_lock import RunLock

    from .storage import STATE_DIR, private_dir, state_path

    if not config.study.is_dir():
        return None, None
    folder = config.study / STATE_DIR
    made = None if folder.exists() else folder
    private_dir(folder)
    try:
        return RunLock(state_path(config.study), "server", busy=lambda holder: (
            f"this study is served already{holder}; stop that server first (one server per "
            "study folder)")).acquire(), made
    except BaseException:
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)
        raise


def serve(config: ServerConfig, listen: Listen,
          on_ready: Callable[[str, str, bool], None] | None = None) -> None:
    """Serve until interrupted. ``on_ready(url, admin_token, token_was_created)`` is called
    once the socket listens (the CLI prints it)."""
    import uvicorn

    from .app import create_app
    from .state import ServerState

    check_listen(listen)
    config.secure_cookies = config.secure_cookies or listen.tls
    sock = bind(listen)  # before the state: a port in use leaves nothing behind
    lock, made = _one_server(config)
    try:
        state = ServerState.open(config)
    except BaseException:
        if lock is not None:
            lock.release()
        if made is not None:  # a failed start leaves no server folder behind
            shutil.rmtree(made, ignore_errors=True)
        sock.close()
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
        if lock is not None:
            lock.release()
