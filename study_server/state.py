"""Everything a running server holds: the study's versions, the database, the upload logic,
rate limits, the admin token and the statistics worker."""

from __future__ import annotations

import logging
import shutil
import threading
from dataclasses import dataclass
from typing import Any

from session_store.errors import StudyError
from session_store.records import utc_now
from session_store.study_folder import MANIFEST_NAME, load_study

from . import auth
from .allocator import Allocator
from .config import ServerConfig
from .dashboard import Pages
from .ingest import Ingest, IngestLimits, Refused
from .ratelimit import RateLimiter
from .stats import StatsWorker
from .storage import STATE_DIR, ServerStore, state_path
from .study_files import FileHashes, StudyVersion, build_version

log = logging.getLogger(__name__)


def prepare_versions(config: ServerConfig, store: ServerStore, hashes: FileHashes
                     ) -> StudyVersion:
    """The study folder's current version, registered in the database. A manifest changed
    while sessions run on the old one is refused unless ``config.new_version``."""
    load_study(config.study)  # a readable study folder with a valid manifest
    raw = (config.study / MANIFEST_NAME).read_bytes()
    current = build_version(config.study, raw, hashes, from_disk=True)
    known = store.versions()
    if any(v.study_id != current.study_id for v in known):
        raise StudyError(
            f"this study folder's server database is for study {known[0].study_id!r}, the "
            f"manifest now says {current.study_id!r}: serve another study from its own folder")
    now_current = next((v for v in known if v.is_current), None)
    if now_current is None or now_current.manifest_sha256 != current.manifest_sha256:
        others = store.sessions_on_other_versions(current.manifest_sha256)
        if others and not config.new_version:
            raise StudyError(
                f"the manifest changed since this study was last served, and {others} "
                "session(s) run on the earlier version: restore the manifest, or pass "
                "--new-version to serve it as a new version (started participants finish on "
                "theirs; new ones get the new one)")
        store.set_current_version(current.manifest_sha256, current.study_id, raw, utc_now())
    return current


@dataclass
class ServerState:
    config: ServerConfig
    store: ServerStore
    current: StudyVersion
    hashes: FileHashes
    admin_token: str
    admin_token_created: bool

    def __post_init__(self) -> None:
        self.study_id = self.current.study_id
        self.ingest = Ingest(self.store, self.study_id, IngestLimits(
            clock_skew_s=self.config.clock_skew_s, offline_gap_s=self.config.offline_gap_s))
        self.limiter = RateLimiter(self.config.rate_per_s, self.config.burst)
        self.failed_auth = RateLimiter(5.0, 50.0)
        self.login_limiter = RateLimiter(0.2, 10.0)
        self.dashboard_logout_ms = self.store.dashboard_logout_ms()
        self._old_versions: dict[str, StudyVersion] = {}
        self._versions_lock = threading.Lock()
        self.stats = StatsWorker(self.config, self.store, self.current)
        self.allocator = Allocator.for_version(self.store, self.current)
        self._allocators: dict[str, Allocator] = {self.current.manifest_sha256: self.allocator}
        self._allocators_started = False
        self.ingest.check_allocation = self._check_allocation
        self.pages = Pages(self.study_id, self.stats, self.sessions_listing,
                           self.config.stats_every_s)

    @classmethod
    def open(cls, config: ServerConfig) -> ServerState:
        """Open (or create) the study's server state. The study folder and its manifest are
        checked first: a failure creates nothing, and a ``server/`` folder made by this call
        is removed again."""
        if config.study.is_file():
            raise StudyError(f"{config.study} is a file; give the study folder that holds "
                             f"{MANIFEST_NAME}")
        load_study(config.study)  # a readable study folder with a valid manifest, first
        state_dir = config.study / STATE_DIR
        fresh = not state_dir.exists()
        store = None
        try:
            store = ServerStore(state_path(config.study))
            hashes = FileHashes()
            current = prepare_versions(config, store, hashes)
            token, created = auth.admin_token(state_dir)
        except BaseException:
            if store is not None:
                store.close()
            if fresh:
                shutil.rmtree(state_dir, ignore_errors=True)
            raise
        return cls(config, store, current, hashes, token, created)

    def start(self) -> None:
        if self.config.stats_in_background:
            self.stats.start()
            with self._versions_lock:
                self._allocators_started = True
                for alloc in self._allocators.values():
                    alloc.start()

    def stop(self) -> None:
        self.stats.stop()
        with self._versions_lock:
            for alloc in self._allocators.values():
                if alloc is not self.allocator:
                    alloc.stop()
        self.allocator.stop()
        self.store.close()

    # -- adaptive allocation, per version ---------------------------------------------
    def allocator_for(self, manifest_sha256: str) -> Allocator | None:
        """The allocator of one served version (None: a version this server never served),
        made when first needed: a participant who started on an earlier version still gets
        their later blocks, planned from that version's fits."""
        with self._versions_lock:
            alloc = self._allocators.get(manifest_sha256)
            if alloc is None:
                alloc = Allocator.of_version(self.store, manifest_sha256, self.study_id)
                if alloc is None:
                    return None
                self._allocators[manifest_sha256] = alloc
                if self._allocators_started:
                    alloc.start()
            return alloc

    def allocator_of(self, pid: str) -> Allocator:
        """The allocator of the version ``pid``'s session runs on (the current one before
        their first upload)."""
        sess = self.store.session_of(pid)
        alloc = None if sess is None else self.allocator_for(sess.manifest_sha256)
        return alloc or self.allocator

    def _check_allocation(self, pid: str, session_id: str, manifest_sha256: str | None,
                          entries: list[Any]) -> str | None:
        alloc = None if manifest_sha256 is None else self.allocator_for(manifest_sha256)
        if alloc is None or not alloc.active:
            return None
        return alloc.check_entries(pid, session_id, manifest_sha256, entries)

    # -- participants -----------------------------------------------------------------
    def check_participant(self, pid: str, token: str) -> None:
        """Refuse (403/410/429) unless ``token`` is ``pid``'s; writes nothing. Failures are
        rate-limited per participant id (a right token always passes, so a stranger
        guessing cannot lock a participant out). A withdrawn id answers 410 to its own token
        only; to anybody else it is a wrong token like any other."""
        p = self.store.participant(pid)
        if p is not None and auth.token_matches(token, p.token_sha256):
            return
        tomb = self.store.tombstone(pid)  # told only to the one who withdrew
        if tomb is not None and tomb.token_sha256 and auth.token_matches(token,
                                                                          tomb.token_sha256):
            raise Refused(410, f"participant {pid} has withdrawn; their data was deleted")
        wait = self.failed_auth.acquire(pid)
        if wait > 0:
            raise Refused(429, "too many failed attempts; try again later", wait)
        raise Refused(403, "this token does not belong to this participant")

    def check_open(self, pid: str) -> None:
        """Refuse (403) a participant who has not started when the study closed at its
        target (``serve --close-at-target``); those who started finish. Asked only when
        the study is fetched (starting), never of uploads: a participant who downloaded
        before the close and rated offline has done the work, and it is kept."""
        if not self.config.stopping.close_at_target:
            return
        status = self.stats.snapshot().stopping
        if status is not None and status.reached and self.store.session_of(pid) is None:
            raise Refused(403, "this study has reached its target and takes no new "
                               "participants; thank you for your interest")

    def version_for(self, pid: str) -> StudyVersion:
        """The version the participant's session is pinned to, else the current one."""
        sess = self.store.session_of(pid)
        if sess is None or sess.manifest_sha256 == self.current.manifest_sha256:
            return self.current
        with self._versions_lock:
            v = self._old_versions.get(sess.manifest_sha256)
        if v is None:
            raw = self.store.version_manifest(sess.manifest_sha256)
            if raw is None:  # pragma: no cover (the foreign key forbids it)
                raise Refused(409, "the session's study version is unknown to this server")
            v = build_version(self.config.study, raw, self.hashes, from_disk=False)
            with self._versions_lock:
                self._old_versions[sess.manifest_sha256] = v
        return v

    # -- the experimenter -------------------------------------------------------------
    def sessions_listing(self) -> dict[str, Any]:
        sessions = {s.participant: s for s in self.store.sessions()}
        flags: dict[str, list[dict[str, Any]]] = {}
        for f in self.store.flags():
            flags.setdefault(f.participant, []).append(
                {"kind": f.kind, "message": f.message, "first_at": f.first_at,
                 "last_at": f.last_at, "count": f.count})
        versions = self.store.versions()
        number = {v.manifest_sha256: i + 1 for i, v in enumerate(versions)}
        last_event = self.store.last_events()
        out = []
        for p in self.store.participants():
            s = sessions.get(p.participant)
            out.append({
                "participant": p.participant, "invited_at": p.invited_at,
                "last_seen": p.last_seen, "clock_offset_ms": p.clock_offset_ms,
                "session": None if s is None else {
                    "session_id": s.session_id, "manifest_sha256": s.manifest_sha256,
                    "version": number.get(s.manifest_sha256), "acked_seq": s.acked_seq,
                    "n_ratings": s.n_ratings, "n_planned": s.n_planned,
                    "first_received": s.first_received, "last_received": s.last_received,
                    "finished_at": s.finished_at, "closed_as": s.closed_as,
                    "app_version": s.app_version,
                    "stopped": last_event.get(s.session_id) == "quit"},
                "flags": flags.get(p.participant, [])})
        return {
            "study_id": self.study_id,
            "versions": [{"version": number[v.manifest_sha256],
                          "manifest_sha256": v.manifest_sha256, "registered_at": v.registered_at,
                          "current": v.is_current} for v in versions],
            "participants": out,
            "withdrawn": [{"participant": t.participant, "withdrawn_at": t.withdrawn_at}
                          for t in self.store.tombstones()],
            "allocation": self.allocator.manifest.protocol.allocation,
            "refits": len(self.allocator.fits()) if self.allocator.active else None,
        }

    def entries_listing(self, pid: str, after: int, limit: int) -> dict[str, Any] | None:
        sess = self.store.session_of(pid)
        if sess is None:
            return None
        rows = self.store.entries(sess.session_id, after, limit)
        return {"participant": pid, "session_id": sess.session_id,
                "acked_seq": sess.acked_seq,
                "entries": [{"seq": e.seq, "kind": e.kind, "body_json": e.body,
                             "prev_hash": e.prev_hash, "entry_hash": e.entry_hash,
                             "client_at": e.client_at, "received_at": e.received_at}
                            for e in rows]}

