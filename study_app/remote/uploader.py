"""Uploading a session file's outbox to the study server, in order, as it grows.

:func:`sync_session` is one pass: a handshake (the server says what it acknowledged, notes the
client's clock and compares the client's change log with what it holds), then every entry
after the acknowledged one, in batches, each answered with the new acknowledged sequence
number (written into the file's ``upload_state``). :class:`Uploader` runs passes on a
background thread: the app calls :meth:`Uploader.notify` after each committed rating
(``RunOptions.on_commit``; it only sets an event, so the presentation loop never waits for
the network, and a pass backing off after an outage tries again at once); offline, passes
fail and are retried with exponential backoff (or the server's ``Retry-After``) until the
server is back. A refusal (a bad token, a contradiction with acknowledged data) stops the
thread: retrying cannot help, and the end screen says so.
"""

from __future__ import annotations

import logging
import random
import re
import sqlite3
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

from session_store import outbox
from session_store.chain import canonical
from session_store.errors import StudyError
from session_store.protocol import CLIENT_BATCH_BYTES, MAX_BATCH_ENTRIES, PROTOCOL, participant_path
from session_store.records import utc_now
from session_store.replica import tables_match_outbox
from session_store.schema import open_existing

from .. import __version__
from .http import ServerClient, ServerRefused, ServerUnavailable

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SyncResult:
    """Where a session stands after a pass: ``acked_seq`` of ``local_seq`` entries arrived."""

    acked_seq: int
    local_seq: int
    sent: int
    """Entries sent in this pass (re-sends included)."""
    requests: int
    clock_offset_ms: float | None = None

    @property
    def complete(self) -> bool:
        return self.acked_seq >= self.local_seq


def local_problems(path: Path) -> list[str]:
    """What the participant's own file says about itself: its tables against its change log,
    the change log's own chain. Reported to the server at the handshake."""
    try:
        return [without_paths(p, path)[:500] for p in tables_match_outbox(path)][:50]
    except StudyError as exc:
        return [without_paths(f"the session file cannot be read ({exc})", path)[:500]]


def without_paths(text: str, path: Path) -> str:
    """``text`` with the session file's folders left out: a participant's home folder
    names their account, which is not the server's to know (only the file name is sent)."""
    for full in {str(path.resolve()), str(path.absolute()), str(path)}:
        text = text.replace(full, path.name)
    return text.replace(str(Path.home()), "~")


def _open(path: Path) -> sqlite3.Connection:
    con = open_existing(path, readonly=False)
    con.execute("PRAGMA busy_timeout=10000")
    con.execute("PRAGMA synchronous=NORMAL")  # a lost ack only means a (harmless) re-send
    if not outbox.has_outbox(con):
        con.close()
        raise StudyError(f"{path} predates uploads (it has no change log); send it back with "
                         "'cgvq-study export' instead")
    return con


def _batches(entries: list[outbox.OutboxEntry]) -> list[list[dict[str, Any]]]:
    out: list[list[dict[str, Any]]] = []
    size = 0
    for e in entries:
        item = e.as_json()
        n = len(canonical(item))
        if out and (size + n > CLIENT_BATCH_BYTES or len(out[-1]) >= MAX_BATCH_ENTRIES):
            out.append([])
            size = 0
        if not out:
            out.append([])
        out[-1].append(item)
        size += n
    return out


def _acked(answer: Any, limit: int) -> int:
    try:
        acked = int(answer["acked_seq"])
    except (KeyError, TypeError, ValueError):
        raise ServerUnavailable("the study server's answer lacks acked_seq") from None
    if not 0 <= acked <= limit:
        raise ServerRefused(f"the study server acknowledged entry {acked}, which this session "
                            f"does not have (it has {limit})", 409)
    return acked


def sync_session(path: str | Path, client: ServerClient, participant: str, *,
                 check_local: bool = True) -> SyncResult:
    """One upload pass of a session file (see the module doc). Raises
    :class:`ServerUnavailable` (try later) or :class:`ServerRefused` (stop)."""
    path = Path(path)
    problems = local_problems(path) if check_local else []
    try:
        con = _open(path)
    except StudyError as exc:  # tell the server before giving up: it flags the participant
        client.json("POST", participant_path(participant, "handshake"), {
            "protocol": PROTOCOL, "session_id": None, "client_time": utc_now(),
            "app_version": __version__, "log_hashes": [],
            "local_problems": [without_paths(f"the session file cannot be opened ({exc})",
                                             path)[:500]]})
        raise
    try:
        con.execute("BEGIN")
        try:  # who the session is, from its change log (the tables may have been edited)
            first = outbox.read_entries(con, after=0, limit=1)
            hashes = [r[0] for r in con.execute("SELECT entry_hash FROM outbox ORDER BY seq")]
        finally:
            con.execute("COMMIT")
        header = first[0].body.get("header", {}) if first else {}
        if header.get("participant") != participant:
            raise StudyError(f"{path} belongs to participant {header.get('participant')!r}, "
                             f"not {participant!r}")
        session_id = header.get("session_id")
        if not isinstance(session_id, str):
            raise StudyError(f"{path}: the change log's first entry is damaged; send the file "
                             "with 'cgvq-study export' instead")
        answer = client.json("POST", participant_path(participant, "handshake"), {
            "protocol": PROTOCOL, "session_id": session_id, "client_time": utc_now(),
            "app_version": __version__, "log_hashes": hashes, "local_problems": problems})
        acked = _acked(answer, len(hashes))
        offset = answer.get("clock_offset_ms") if isinstance(answer, dict) else None
        sent, requests = 0, 1
        while True:
            entries = outbox.read_entries(con, after=acked, limit=MAX_BATCH_ENTRIES)
            if not entries:
                break
            for batch in _batches(entries):
                answer = client.json("POST", participant_path(participant, "entries"), {
                    "protocol": PROTOCOL, "session_id": session_id, "client_time": utc_now(),
                    "entries": batch})
                requests += 1
                sent += len(batch)
                acked = _acked(answer, batch[-1]["seq"])
                outbox.set_upload_state(con, "acked_seq", str(acked))
                outbox.set_upload_state(con, "acked_at", utc_now())
        local_seq = int(con.execute("SELECT coalesce(max(seq), 0) FROM outbox").fetchone()[0])
        return SyncResult(acked, local_seq, sent, requests,
                          float(offset) if isinstance(offset, int | float) else None)
    finally:
        con.close()


WITHDRAWN = "you were withdrawn from the study, and your answers on the server were deleted"
"""What a 410 of the study server means, in the participant's words."""

State = Literal["starting", "sending", "up to date", "offline", "refused", "stopped"]


@dataclass(frozen=True)
class UploadStatus:
    """What the app shows: how much arrived, and why not everything (when so)."""

    state: State
    acked_seq: int = 0
    local_seq: int = 0
    error: str | None = None
    last_success: float | None = None
    """time.monotonic() of the last successful pass."""
    withdrawn: bool = False
    """The server refused because the participant was withdrawn (410): nothing is to be sent
    again, and nothing continued."""
    pending: tuple[tuple[str, int], ...] = ()
    """What has not arrived, by kind of change (``rating``, ``answer``, ``withdrawn``...),
    as the session file says when the last pass failed or the app asked."""

    @property
    def all_arrived(self) -> bool:
        return self.local_seq > 0 and self.acked_seq >= self.local_seq

    def describe(self) -> str:
        """One sentence for the end screen."""
        if self.all_arrived:
            return "All your answers have arrived at the study server."
        missing = max(self.local_seq - self.acked_seq, 0)
        if self.withdrawn:
            return (f"The study server no longer accepts answers from you ({WITHDRAWN}); "
                    "there is nothing more to do or to send. If this is a mistake, contact the "
                    "experimenter.")
        if self.state == "refused":
            return (f"The study server refused the upload ({self.error}). Please contact the "
                    "experimenter and send your session file with 'cgvq-study export'.")
        why = participant_reason(self.error)
        pending = dict(self.pending)
        again = ("start the study once more the same way when you are online (your "
                 "invitation, or the command the experimenter gave you)")
        if pending.get("withdrawn"):
            return (f"Your withdrawal has not reached the study server yet ({why}). Please "
                    f"{again}: it only sends your withdrawal. Or write to the experimenter "
                    "that you withdrew.")
        answers = pending.get("rating", 0) + pending.get("answer", 0)
        what = (f"{answers} of your answers {'is' if answers == 1 else 'are'} not on the "
                "study server yet" if answers else
                "The last steps of your session are not on the study server yet" if pending
                or missing else "Your answers are not on the study server yet")
        return (f"{what} ({why}). They are safe on this computer: {again}, and it sends only "
                "what is missing.")


class Uploader:
    """Background upload of one session file (see the module doc). It may start before the
    file exists (it waits for it) and looks at the file every ``idle_check_s`` seconds even
    without :meth:`notify`, so the app needs no hook to keep it going: a local look costs
    one small read; a request goes out only when there is something new."""

    def __init__(self, path: str | Path, client: ServerClient, participant: str, *,
                 min_backoff_s: float = 1.0, max_backoff_s: float = 60.0,
                 idle_check_s: float = 2.0, seed: int | None = None) -> None:
        self.path = Path(path)
        self.client = client
        self.participant = participant
        self.min_backoff_s = min_backoff_s
        self.max_backoff_s = max_backoff_s
        self.idle_check_s = idle_check_s
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._status = UploadStatus("starting")
        self._rng = random.Random(seed)
        self._thread = threading.Thread(target=self._run, name=f"uploader-{participant}",
                                        daemon=True)
        self._checked_local = False

    # -- control (any thread) ---------------------------------------------------------
    def start(self) -> Uploader:
        self._thread.start()
        return self

    def notify(self) -> None:
        """Something new was committed: upload soon. Never blocks."""
        self._wake.set()

    @property
    def status(self) -> UploadStatus:
        with self._lock:
            return self._status

    def flush(self, timeout: float) -> UploadStatus:
        """Wait (at most ``timeout`` seconds) until everything arrived or the server refused;
        the status either way."""
        deadline = time.monotonic() + timeout
        # what the file holds now: the thread may not have looked since the last change
        need = _local_seq(self.path) if self.path.exists() else 0
        self.notify()
        with self._changed:
            while True:
                st = self._status
                if st.local_seq < need:
                    st = replace(st, local_seq=need)
                if st.all_arrived or st.state in ("refused", "stopped") or \
                        not self.path.exists():
                    return self._with_file(st)
                left = deadline - time.monotonic()
                if left <= 0 or not self._thread.is_alive():
                    return self._with_file(st)
                self._changed.wait(min(left, 0.5))

    def _with_file(self, st: UploadStatus) -> UploadStatus:
        """``st`` with what the session file says has and has not arrived (a run whose passes
        all failed knows only what earlier runs stored in the file)."""
        if st.all_arrived or not self.path.exists():
            return st
        local, acked, pending = outbox_state(self.path)
        acked = max(st.acked_seq, acked)
        if acked >= max(local, st.local_seq) > 0:
            return replace(st, acked_seq=acked, local_seq=max(local, st.local_seq))
        return replace(st, acked_seq=acked, local_seq=max(local, st.local_seq),
                       pending=pending)

    def stop(self, timeout: float = 5.0) -> UploadStatus:
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout)
        return self.status

    # -- the thread -------------------------------------------------------------------
    def _set(self, **changes: Any) -> None:
        with self._changed:
            self._status = replace(self._status, **changes)
            self._changed.notify_all()

    def _run(self) -> None:
        failures = 0
        synced = False
        while not self._stop.is_set():
            self._wake.clear()
            delay = self.idle_check_s
            if not self.path.exists():  # the app has not created the session file yet
                self._wake.wait(delay)
                continue
            if synced and failures == 0:  # a cheap local look before any request
                local = _local_seq(self.path)
                if local <= self.status.acked_seq:
                    self._set(local_seq=local)
                    self._wake.wait(delay)
                    continue
            self._set(state="sending")
            try:
                result = sync_session(self.path, self.client, self.participant,
                                      check_local=not self._checked_local)
                self._checked_local = synced = True
                failures = 0
                self._set(state="up to date" if result.complete else "sending",
                          acked_seq=result.acked_seq, local_seq=result.local_seq, error=None,
                          last_success=time.monotonic())
                if not result.complete:
                    delay = 0.0
            except ServerRefused as exc:
                log.warning("upload of %s refused: %s", self.path, exc)
                self._set(state="refused", error=exc.detail or str(exc),
                          withdrawn=exc.status == 410)
                break
            except (ServerUnavailable, sqlite3.Error) as exc:
                failures += 1
                cap = min(self.max_backoff_s, self.min_backoff_s * 2 ** min(failures - 1, 16))
                delay = self._rng.uniform(cap / 2, cap)
                if isinstance(exc, ServerUnavailable) and exc.retry_after is not None:
                    delay = max(delay, min(exc.retry_after, self.max_backoff_s))
                log.debug("upload of %s postponed %.1f s: %s", self.path, delay, exc)
                local, acked, pending = outbox_state(self.path)
                self._set(state="offline", error=str(exc), local_seq=local, pending=pending,
                          acked_seq=max(self.status.acked_seq, acked))
            except StudyError as exc:
                log.warning("upload of %s stopped: %s", self.path, exc)
                self._set(state="refused", error=str(exc))
                break
            if delay > 0:
                self._wake.wait(delay)
        if self.status.state != "refused":
            self._set(state="stopped")


def participant_reason(error: str | None) -> str:
    """Why the upload has not gone through, in a participant's words: no server address, no
    nested brackets ("the study server cannot be reached: connection refused")."""
    if not error:
        return "it is still being sent"
    m = re.fullmatch(r"cannot reach the study server \S+ \((.*)\)", error)
    if m:
        return f"the study server cannot be reached: {m.group(1)}"
    return error.replace("(", "- ").replace(")", "")


def outbox_state(path: Path) -> tuple[int, int, tuple[tuple[str, int], ...]]:
    """(last change, last change the server acknowledged, the changes not acknowledged by
    kind) as the session file holds them; zeros when it cannot be read."""
    try:
        con = open_existing(path, readonly=True)
    except StudyError:
        return 0, 0, ()
    try:
        local = int(con.execute("SELECT coalesce(max(seq), 0) FROM outbox").fetchone()[0])
        acked = outbox.acked_seq(con)
        kinds = con.execute("SELECT kind, count(*) FROM outbox WHERE seq > ? GROUP BY kind "
                            "ORDER BY kind", (acked,)).fetchall()
        return local, acked, tuple((str(k), int(n)) for k, n in kinds)
    except sqlite3.Error:
        return 0, 0, ()
    finally:
        con.close()


def _local_seq(path: Path) -> int:
    try:
        con = open_existing(path, readonly=True)
    except StudyError:
        return 0
    try:
        return int(con.execute("SELECT coalesce(max(seq), 0) FROM outbox").fetchone()[0])
    except sqlite3.Error:
        return 0
    finally:
        con.close()
