"""Receiving a participant's uploads: the checks, the anchor, the flags.

The server is the anchor: an entry it acknowledged cannot be rewritten. Each participant's
session is mirrored by a :class:`~session_store.Replica` (held in memory, rebuilt from the
database after a restart) that applies received entries through the same mutations as the
participant's app, so an entry is stored only when it continues the chain (sequence numbers,
hashes recomputed from content) and fits the session (a rating of the next planned trial,
with a row hash that matches its content...). Entries go into the database and the replica in
one step: the replica's transaction commits only after the database's did.

What contradicts acknowledged data (an edited or removed entry, a second session file, a
header for another study or version) is refused with 409 and flagged for the participant; a
malformed request is refused with 4xx and writes nothing. Each stored entry keeps the client's
time of the change and the server's receive time; the clock offset taken at the handshake
turns one into the other, so uploads long after the fact (offline) and skewed clocks are
flagged too.
"""

from __future__ import annotations

import collections
import json
import logging
import re
import sqlite3
import threading
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, StrictStr, ValidationError

from session_store.chain import canonical
from session_store.errors import StudyError
from session_store.mutations import APPLY
from session_store.outbox import OutboxEntry
from session_store.protocol import (
    CLOCK_SKEW_LIMIT_S,
    MAX_BATCH_ENTRIES,
    OFFLINE_GAP_LIMIT_S,
    PROTOCOL,
)
from session_store.records import utc_now
from session_store.replica import ContradictionError, Replica
from stimuli_manifests import parse_manifest
from stimuli_manifests.panel import PanelError

from .content import StudyDesign, content_problem, parse_time
from .storage import ServerStore, SessionRow, StoredEntry

log = logging.getLogger(__name__)

_HOME = re.compile(r"(?:/home|/Users)/[^/\\\s]+|[A-Za-z]:\\Users\\[^\\/]+", re.IGNORECASE)


def without_home(text: str) -> str:
    """Client text with home folders as ``~``: the genuine app sends none, an altered or
    older one may, and a home folder names the participant's account."""
    return _HOME.sub("~", text)

Hex64 = Annotated[StrictStr, Field(pattern=r"^[0-9a-f]{64}$")]
SessionId = Annotated[StrictStr, Field(pattern=r"^[0-9A-Za-z_-]{1,64}$")]
Time = Annotated[StrictStr, Field(max_length=40)]
KINDS = tuple(APPLY)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class EntryIn(_Model):
    seq: Annotated[StrictInt, Field(ge=1, le=10_000_000)]
    kind: Literal[KINDS]  # type: ignore[valid-type]
    body: dict[str, Any]
    prev_hash: Hex64
    entry_hash: Hex64

    def entry(self) -> OutboxEntry:
        return OutboxEntry(self.seq, self.kind, self.body, self.prev_hash, self.entry_hash)


class UploadIn(_Model):
    protocol: Literal[PROTOCOL]  # type: ignore[valid-type]
    session_id: SessionId
    client_time: Time
    entries: Annotated[list[EntryIn], Field(min_length=1, max_length=MAX_BATCH_ENTRIES)]


class HandshakeIn(_Model):
    protocol: Literal[PROTOCOL]  # type: ignore[valid-type]
    session_id: SessionId | None
    client_time: Time
    app_version: Annotated[StrictStr, Field(max_length=64)]
    log_hashes: Annotated[list[Hex64], Field(max_length=100_000)]
    local_problems: Annotated[list[Annotated[StrictStr, Field(max_length=500)]],
                              Field(max_length=50)]


class Refused(Exception):  # noqa: N818 (an answer, not a bug)
    """An upload the server does not take; ``status`` is the HTTP status to answer with."""

    def __init__(self, status: int, detail: str, retry_after: float | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.retry_after = retry_after


def parse(model: type[BaseModel], data: Any) -> Any:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "body"
        raise Refused(422, f"malformed request: {where}: {first['msg']}") from None


def client_time_of(e: OutboxEntry) -> str | None:
    """When the client made this change, by its own clock."""
    b = e.body
    try:
        if e.kind == "session":
            value = b["header"]["created_at"]
        elif e.kind == "rating":
            value = b["row"]["answered_at"]
        elif e.kind == "requeue":
            value = b["presentation"]["logged_at"]
        else:
            value = b["at"]
    except (KeyError, TypeError):
        return None
    return value if parse_time(value) is not None else None


def _short(value: Any) -> str:
    """A client's value in a message: quoted and cut short (flags and the log are bounded)."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _span(seqs: list[int]) -> str:
    return f"{seqs[0]}" if len(seqs) == 1 else f"{seqs[0]}-{seqs[-1]}"


@dataclass
class IngestLimits:
    clock_skew_s: float = CLOCK_SKEW_LIMIT_S
    offline_gap_s: float = OFFLINE_GAP_LIMIT_S
    cached_sessions: int = 512


class Ingest:
    """The upload logic over a :class:`ServerStore` (no HTTP here; see :mod:`.app`)."""

    def __init__(self, store: ServerStore, study_id: str, limits: IngestLimits | None = None
                 ) -> None:
        self.store = store
        self.study_id = study_id
        self.limits = limits or IngestLimits()
        self._replicas: collections.OrderedDict[str, Replica] = collections.OrderedDict()
        self._cache_lock = threading.Lock()
        self._locks: dict[str, threading.Lock] = collections.defaultdict(threading.Lock)
        self._locks_lock = threading.Lock()
        self._designs: dict[str, StudyDesign] = {}
        self.check_allocation: Callable[[str, str, str | None, list[OutboxEntry]],
                                        str | None] | None = None
        """Set by the server for adaptive studies (:meth:`.allocator.Allocator.check_entries`)."""

    # -- helpers ----------------------------------------------------------------------
    def _lock(self, pid: str) -> threading.Lock:
        with self._locks_lock:
            return self._locks[pid]

    def flag(self, pid: str, session_id: str | None, kind: str, message: str) -> None:
        """Record a flag; the log gets each distinct flag once, not every repeat."""
        if self.store.add_flag(pid, session_id, kind, message, utc_now()):
            log.warning("flag %s for %s: %s", kind, pid, message)

    def _replica(self, sess: SessionRow) -> Replica:
        with self._cache_lock:
            rep = self._replicas.get(sess.session_id)
            if rep is not None:
                self._replicas.move_to_end(sess.session_id)
        if rep is not None and rep.head()[0] == sess.acked_seq:
            return rep
        stored = self.store.entries(sess.session_id)
        entries = [OutboxEntry(s.seq, s.kind, json.loads(s.body), s.prev_hash, s.entry_hash)
                   for s in stored]
        rep = Replica.in_memory(entries[0])
        rep.accept(entries[1:])
        self._cache(sess.session_id, rep)
        return rep

    def _cache(self, session_id: str, rep: Replica) -> None:
        with self._cache_lock:
            old = self._replicas.pop(session_id, None)
            if old is not None and old is not rep:
                old.close()
            self._replicas[session_id] = rep
            while len(self._replicas) > self.limits.cached_sessions:
                # only dropped, not closed: its owner's upload may be using it right now
                # (this holds the cache lock, not theirs); it closes when the last user
                # lets go of it
                self._replicas.popitem(last=False)

    def forget(self, session_id: str) -> None:
        with self._cache_lock:
            rep = self._replicas.pop(session_id, None)
        if rep is not None:
            rep.close()

    # -- handshake --------------------------------------------------------------------
    def handshake(self, pid: str, data: Any, address: str | None) -> dict[str, Any]:
        msg: HandshakeIn = parse(HandshakeIn, data)
        now = datetime.now(UTC)
        received = _iso(now)
        client = parse_time(msg.client_time)
        offset_ms = None if client is None else (now - client).total_seconds() * 1000.0
        with self._lock(pid):
            self.store.touch(pid, received, address, offset_ms)
            sess = self.store.session_of(pid)
            sid = sess.session_id if sess else msg.session_id
            if offset_ms is not None and abs(offset_ms) / 1000 > self.limits.clock_skew_s:
                self.flag(pid, sid, "clock_skew",
                          f"the participant's clock is {abs(offset_ms) / 60000:.0f} min "
                          f"{'behind' if offset_ms > 0 else 'ahead of'} the server's")
            for problem in msg.local_problems:
                self.flag(pid, sid, "local_edit",
                          f"the participant's own file: {without_home(problem)}")
            if sess is None:
                return self._answer(0, received, offset_ms)
            if msg.session_id is not None and msg.session_id != sess.session_id:
                detail = (f"this participant's session on the server is {sess.session_id}; "
                          f"the file sent is another session ({msg.session_id}): a second "
                          "session file (deleted and started again?) is not accepted")
                self.flag(pid, sid, "second_session", detail)
                raise Refused(409, detail)
            held = self.store.entry_hashes(sess.session_id)
            for seq, (mine, theirs) in enumerate(zip(held, msg.log_hashes, strict=False),
                                                 start=1):
                if mine != theirs:
                    detail = (f"entry {seq} of the participant's file differs from the one the "
                              "server acknowledged: the file was changed after upload")
                    self.flag(pid, sid, "contradiction", detail)
                    raise Refused(409, detail)
            if msg.session_id is not None and len(msg.log_hashes) < len(held):
                detail = (f"the participant's file lacks entries {len(msg.log_hashes) + 1}-"
                          f"{len(held)}, which the server acknowledged: they were removed "
                          "after upload")
                self.flag(pid, sid, "contradiction", detail)
                raise Refused(409, detail)
            return self._answer(sess.acked_seq, received, offset_ms)

    @staticmethod
    def _answer(acked: int, received: str, offset_ms: float | None) -> dict[str, Any]:
        return {"acked_seq": acked, "server_time": received, "clock_offset_ms": offset_ms}

    # -- upload -----------------------------------------------------------------------
    def _design(self, manifest_sha256: str) -> StudyDesign:
        """The design of a study version this server serves, cached per version. Only a
        known sha is ever looked up (the header is checked first), so the cache is bounded
        by the versions in the database, never by what clients send."""
        with self._cache_lock:
            design = self._designs.get(manifest_sha256)
        if design is None:
            raw = self.store.version_manifest(manifest_sha256)
            if raw is None:
                raise Refused(409, "the session's study version is unknown to this server")
            design = StudyDesign.of(parse_manifest(json.loads(raw), source="manifest"))
            with self._cache_lock:
                self._designs[manifest_sha256] = design
        return design

    def _check_answers(self, pid: str, session_id: str, design: StudyDesign,
                       entries: list[OutboxEntry]) -> None:
        """Answers must be valid answers to the study's questions (the app checks them with
        the same rule, so only an altered client sends others); the refusal and the flag
        never repeat a free-text answer."""
        panel = design.panel
        for e in entries:
            if e.kind != "answer":
                continue
            body = e.body
            try:
                if panel is None:
                    raise PanelError("the study asks no questionnaire")
                panel.check(str(body.get("questionnaire")), str(body.get("question")),
                            body.get("value"))
            except PanelError as exc:
                detail = f"entry {e.seq}: answer refused: {exc}"
                self.flag(pid, session_id, "answer", detail)
                raise Refused(422, detail) from None

    def _check_content(self, pid: str, session_id: str, design: StudyDesign,
                       entries: list[OutboxEntry]) -> None:
        """Every entry's types and its fit with the study (:mod:`.content`): refused (422)
        and flagged, before anything is applied or cached."""
        for e in entries:
            problem = content_problem(design, e)
            if problem is not None:
                self.flag(pid, session_id, "content", problem)
                raise Refused(422, f"upload refused: {problem}")

    def _check_allocation(self, pid: str, session_id: str, sha: str,
                          entries: list[OutboxEntry]) -> None:
        """The adaptive allocation's own check (blocks this server issued), as a 409."""
        if self.check_allocation is None:
            return
        try:
            problem = self.check_allocation(pid, session_id, sha, entries)
        except (KeyError, TypeError, ValueError, IndexError, OverflowError):
            problem = "a block entry is malformed"
        if problem is not None:
            self.flag(pid, session_id, "allocation", problem)
            raise Refused(409, f"upload refused: {problem}")

    def upload(self, pid: str, data: Any, address: str | None) -> dict[str, Any]:
        msg: UploadIn = parse(UploadIn, data)
        entries = sorted((e.entry() for e in msg.entries), key=lambda e: e.seq)
        now = datetime.now(UTC)
        with self._lock(pid):
            participant = self.store.participant(pid)
            offset_ms = participant.clock_offset_ms if participant else None
            sess = self.store.session_of(pid)
            if sess is None:
                first = entries[0]
                if first.seq != 1 or first.kind != "session":
                    raise Refused(409, f"the server holds no session of {pid} yet: send from "
                                       "entry 1 (the session's header and plan)")
                sha = str(self._check_header(pid, msg.session_id, first)["manifest_sha256"])
            else:
                sha = sess.manifest_sha256
            design = self._design(sha)
            self._check_content(pid, msg.session_id, design, entries)
            self._check_answers(pid, msg.session_id, design, entries)
            self._check_allocation(pid, msg.session_id, sha, entries)
            if sess is None:
                acked = self._first_upload(pid, msg.session_id, entries, now, offset_ms,
                                           address)
            else:
                acked = self._continue(pid, sess, msg.session_id, entries, now, offset_ms,
                                       address)
        return {"acked_seq": acked, "server_time": _iso(now)}

    def _check_header(self, pid: str, session_id: str, first: OutboxEntry) -> dict[str, Any]:
        header = first.body.get("header")
        if not isinstance(header, dict):
            raise Refused(422, "the session entry has no header")
        problems = []
        if header.get("session_id") != session_id:
            problems.append("its session id differs from the upload's")
        if header.get("participant") != pid:
            problems.append(f"it belongs to participant {_short(header.get('participant'))}")
        if header.get("study_id") != self.study_id:
            problems.append(f"it is for study {_short(header.get('study_id'))}, not "
                            f"{self.study_id!r}")
        sha = header.get("manifest_sha256")
        known = {v.manifest_sha256 for v in self.store.versions()}
        if not isinstance(sha, str) or sha not in known:
            problems.append("it was made for a manifest this server never served "
                            f"({str(sha)[:12]}...)")
        if problems:
            detail = "the session header does not fit this study: " + "; ".join(problems)
            self.flag(pid, session_id, "header", detail)
            raise Refused(409, detail)
        return header

    def _first_upload(self, pid: str, session_id: str, entries: list[OutboxEntry],
                      now: datetime, offset_ms: float | None, address: str | None) -> int:
        first = entries[0]
        header = self._check_header(pid, session_id, first)
        try:
            rep = Replica.in_memory(first)
        except (StudyError, sqlite3.Error, AttributeError, OverflowError) as exc:
            self.flag(pid, session_id, "refused", f"session entry refused: {exc}")
            raise Refused(422, f"the session entry is refused: {exc}") from None
        try:
            acked = self._apply(pid, session_id, rep, entries, now, offset_ms, new_session={
                "manifest_sha256": header["manifest_sha256"],
                "app_version": str(header.get("app_version", ""))[:64],
                "created_at": str(header.get("created_at", ""))[:40]}, include_first=True,
                address=address)
        except BaseException:
            rep.close()
            raise
        self._cache(session_id, rep)
        return acked

    def _continue(self, pid: str, sess: SessionRow, session_id: str,
                  entries: list[OutboxEntry], now: datetime, offset_ms: float | None,
                  address: str | None) -> int:
        if session_id != sess.session_id:
            detail = (f"this participant's session on the server is {sess.session_id}; the "
                      f"upload is for another session ({session_id}): a second session file "
                      "is not accepted")
            self.flag(pid, session_id, "second_session", detail)
            raise Refused(409, detail)
        rep = self._replica(sess)
        return self._apply(pid, session_id, rep, entries, now, offset_ms, address=address)

    def _apply(self, pid: str, session_id: str, rep: Replica, entries: list[OutboxEntry],
               now: datetime, offset_ms: float | None, *, new_session: dict | None = None,
               include_first: bool = False, address: str | None = None) -> int:
        received = _iso(now)
        try:
            with rep.staged(entries[1:] if include_first else entries) as fresh:
                todo = ([entries[0]] if include_first else []) + fresh
                if todo:
                    stored = [StoredEntry(e.seq, e.kind, canonical(e.body), e.prev_hash,
                                          e.entry_hash, client_time_of(e), received)
                              for e in todo]
                    self.store.store_entries(participant=pid, session_id=session_id,
                                             entries=stored, state=rep.summary(),
                                             new_session=new_session, address=address)
        except ContradictionError as exc:
            self.flag(pid, session_id, "contradiction", str(exc))
            raise Refused(409, str(exc)) from None
        except (StudyError, sqlite3.IntegrityError, AttributeError, OverflowError) as exc:
            self.forget(session_id)
            why = str(exc).removeprefix("upload refused: ")  # the replica's own words
            self.flag(pid, session_id, "refused", f"upload refused: {why}")
            raise Refused(409, f"upload refused: {why}") from None
        except BaseException:
            self.forget(session_id)
            raise
        if todo:
            self._offline_gaps(pid, session_id, todo, now, offset_ms)
        return rep.head()[0]

    def _offline_gaps(self, pid: str, session_id: str, entries: list[OutboxEntry],
                      now: datetime, offset_ms: float | None) -> None:
        late = []
        worst = 0.0
        for e in entries:
            t = parse_time(client_time_of(e))
            if t is None:
                continue
            delay = (now - t).total_seconds() - (offset_ms or 0.0) / 1000.0
            if delay > self.limits.offline_gap_s:
                late.append(e.seq)
                worst = max(worst, delay)
        if late:
            self.flag(pid, session_id, "offline_gap",
                      f"entries {_span(late)} arrived up to {worst / 60:.0f} min after they "
                      "were written (offline meanwhile)")


def _iso(t: datetime) -> str:
    return t.isoformat(timespec="milliseconds").replace("+00:00", "Z")
