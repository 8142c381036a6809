"""Simulated participants uploading to a study server while they rate (``cgvq-study
simulate --server``): every rater at once, one thread each, through the app's own uploader,
with outages and arrivals over time when asked for."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from .remote import ServerClient, ServerUnavailable, Uploader, UploadStatus
from .remote.participant import request_block

T = TypeVar("T")

NextBlock = Callable[[str, int, str | None], dict[str, Any]]
"""(session id, block, last stimulus) -> the study server's block (``id``, ``stimuli``)."""


@dataclass(frozen=True)
class UploadOptions:
    """Simulated participants uploading to a study server as they rate (``simulate
    --server``), through the same upload client as the app."""

    server: str
    tokens: dict[str, str]
    """participant id -> token (from the invites CSV); the raters take these ids in order."""
    pace_s: float = 0.0
    """Seconds between two ratings of one rater (0: as fast as possible)."""
    stagger_s: float = 0.0
    """Rater ``k`` starts ``k * stagger_s`` seconds after the first (participants arriving
    over time; 0: all at once)."""
    start_gate: Callable[[int], None] | None = None
    """Called in rater ``k``'s thread after its stagger, before it starts: it returns when
    the rater may arrive (e.g. once the server has refit its adaptive model)."""
    offline: dict[str, tuple[float, float]] = field(default_factory=dict)
    """participant -> (from, until) seconds after the start: their network is down then."""
    timeout_s: float = 600.0
    """How long to wait at the end for every upload to arrive."""
    min_backoff_s: float = 0.2
    max_backoff_s: float = 5.0
    client_factory: Callable[[str, str], ServerClient] | None = None
    """Makes each rater's client from (server, token); e.g. one that times its requests."""


class _OfflineClient(ServerClient):
    """A participant whose network is down for a while (simulated outage)."""

    def __init__(self, server: str, token: str, down: tuple[float, float], t0: float) -> None:
        super().__init__(server, token)
        self._down = (t0 + down[0], t0 + down[1])

    def open(self, *args: Any, **kwargs: Any) -> Any:
        if self._down[0] <= time.monotonic() < self._down[1]:
            raise ServerUnavailable("simulated network outage")
        return super().open(*args, **kwargs)


def rate_and_upload(rater: Callable[..., T], participants: list[str], out: Path,
                    upload: UploadOptions, t0: float, suffix: str
                    ) -> tuple[list[T], dict[str, UploadStatus]]:
    """Every rater at once, each in a thread, each with its uploader (the app's)."""
    uploaders: dict[str, Uploader] = {}
    results: dict[int, T] = {}
    errors: list[BaseException] = []

    def one(k: int) -> None:
        pid = participants[k]
        time.sleep(k * upload.stagger_s)
        if upload.start_gate is not None:
            try:
                upload.start_gate(k)
            except BaseException as exc:
                errors.append(exc)
                return
        down = upload.offline.get(pid)
        make = upload.client_factory or ServerClient
        client = (_OfflineClient(upload.server, upload.tokens[pid], down, t0) if down
                  else make(upload.server, upload.tokens[pid]))
        up = Uploader(out / f"{pid}{suffix}", client, pid,
                      min_backoff_s=upload.min_backoff_s, max_backoff_s=upload.max_backoff_s,
                      seed=k)
        uploaders[pid] = up
        started = False

        def changed() -> None:
            nonlocal started
            if not started:  # the uploader starts once the session file exists
                up.start()
                started = True
            up.notify()

        def next_block(session_id: str, block: int, last: str | None) -> dict[str, Any]:
            """As the app: wait for the uploads, ask; retry while the server is away."""
            while True:
                try:
                    return request_block(client, pid, up, session_id, block, last)
                except ServerUnavailable:
                    time.sleep(upload.min_backoff_s)

        try:
            results[k] = rater(k, changed, next_block)
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=one, args=(k,), name=f"rater-{participants[k]}")
               for k in range(len(participants))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        for up in uploaders.values():
            up.stop()
        raise errors[0]
    deadline = time.monotonic() + upload.timeout_s
    statuses = {}
    for pid, up in uploaders.items():
        statuses[pid] = up.flush(max(deadline - time.monotonic(), 0.1))
        up.stop()
    return [results[k] for k in range(len(participants))], statuses
