"""Adaptive allocation on the server: background refits, the blocks issued, their log.

A study with ``protocol.allocation: adaptive`` (:mod:`stimuli_manifests.allocation`) runs each
session as blocks. Block 1 (every stimulus once) is planned by the app from the session's
seed; the server checks it. Each later block is asked for at the end of the one before and
planned here:

- **Refit in the background.** A worker refits the analysis' model (SUREAL MLE and rater
  bootstrap, through :mod:`.analysis_adapter`) at most every ``refit_seconds`` when ratings
  arrived, once ``warmup_participants`` sessions have finished block 1; a request never fits.
  Each fit is logged with what it used: the number of ratings of every session, in each
  session's own order (uploads arrive in order, so this fixes the input exactly).
- **Issue.** A block is planned from the latest fit and the ratings *pending* since it
  (planned in blocks issued to open sessions, or arrived after the fit), so two participants
  starting together do not get the same stimuli; before the first fit, blocks are uniform.
  A session silent for :data:`PENDING_EXPIRY_S` no longer holds its unrated trials: a
  participant who took a block and left would otherwise keep those stimuli (the widest
  ones) from every later plan.
  The trial order comes from the session's seed and the block number. The block, the fit it
  used and those inputs are logged; asking again for the same block returns the same one.
- **Audit.** :meth:`Allocator.replay` refits every logged fit from the stored ratings and
  re-plans every logged block from its logged inputs; any difference is reported.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from session_store.chain import canonical
from session_store.errors import StudyError
from session_store.records import utc_now
from session_store.schedule import block_seed, order_trials, schedule_items, uniform_counts
from stimuli_manifests import Manifest, parse_manifest

from .ingest import Refused
from .storage import ServerStore
from .study_files import StudyVersion
from .worker import ThrottledWorker

log = logging.getLogger(__name__)

#: An open session from which nothing arrived for this long (an hour) is taken to be
#: abandoned: its unrated trials stop counting as pending. Uploads follow each rating, so a
#: participant still rating, breaks included, is heard from far more often.
PENDING_EXPIRY_S = 3600.0


@dataclass(frozen=True)
class IssuedBlock:
    """A block as the participant's app receives it."""

    block: int
    block_id: str
    stimuli: list[str]

    def answer(self) -> dict[str, Any]:
        return {"block": self.block, "id": self.block_id, "stimuli": self.stimuli,
                "issued_by": "server"}


def block_id(session_id: str, block: int, stimuli: list[str]) -> str:
    digest = hashlib.sha256(canonical([session_id, block, stimuli]).encode()).hexdigest()
    return f"b{block}-{digest[:16]}"


class Allocator:
    """Adaptive allocation for one version of the study (inactive for ``full``). The server
    keeps one per version that has sessions, so participants who started on an earlier
    version get their later blocks planned from that version's own fits."""

    def __init__(self, store: ServerStore, manifest_bytes: bytes, manifest_sha256: str,
                 study_id: str) -> None:
        self.store = store
        self.manifest_bytes = manifest_bytes
        self.manifest_sha256 = manifest_sha256
        self.study_id = study_id
        self.manifest: Manifest = parse_manifest(json.loads(manifest_bytes), source="manifest")
        self.settings = self.manifest.protocol.adaptive_settings()
        self.items = schedule_items(self.manifest)
        self.ids = [it.id for it in self.items]
        self._lock = threading.Lock()
        self._worker = ThrottledWorker(
            "allocation-refit", self.settings.refit_seconds if self.settings else 30.0,
            self.refit, before=_warm_up, join_s=120.0)

    @classmethod
    def for_version(cls, store: ServerStore, version: StudyVersion) -> Allocator:
        return cls(store, version.manifest_bytes, version.manifest_sha256, version.study_id)

    @classmethod
    def offline(cls, store: ServerStore) -> Allocator:
        """Over the current version in a server database (no server running)."""
        current = next((v for v in store.versions() if v.is_current), None)
        if current is None:
            raise StudyError("the study has not been served yet: there is no allocation log")
        alloc = cls.of_version(store, current.manifest_sha256, current.study_id)
        if alloc is None:
            raise StudyError("the study has not been served yet: there is no allocation log")
        return alloc

    @classmethod
    def of_version(cls, store: ServerStore, manifest_sha256: str, study_id: str
                   ) -> Allocator | None:
        """Over one version the server has served (None: it does not know that version)."""
        raw = store.version_manifest(manifest_sha256)
        return None if raw is None else cls(store, raw, manifest_sha256, study_id)

    @classmethod
    def every_version(cls, store: ServerStore) -> list[tuple[bool, Allocator]]:
        """(is current, allocator) of every version served, the current one first."""
        out = []
        for v in sorted(store.versions(), key=lambda v: not v.is_current):
            alloc = cls.of_version(store, v.manifest_sha256, v.study_id)
            if alloc is not None:
                out.append((bool(v.is_current), alloc))
        return out

    @property
    def active(self) -> bool:
        return self.settings is not None

    # -- the background refit ---------------------------------------------------------
    def start(self) -> None:
        if self.active:
            self._worker.start()

    def stop(self) -> None:
        self._worker.stop()

    def poke(self) -> None:
        """New ratings arrived (the worker refits when it is due)."""
        self._worker.poke()

    def _rating_rows(self) -> list[tuple[str, str, str, str, str]]:
        """Every stored rating entry of the current version, per session in upload order."""
        rows = self.store.entries_of_kinds(["rating"])
        return [r for r in rows if r[1] == self.manifest_sha256]

    def _sessions_in(self, rows: list[tuple[str, str, str, str, str]]) -> dict[str, int]:
        used: Counter[str] = Counter(r[4] for r in rows)
        return dict(sorted(used.items()))

    def refit(self) -> int | None:
        """Fit now if the ratings changed since the last fit and enough sessions finished
        block 1; the new fit's id (None: no fit)."""
        assert self.settings is not None
        rows = self._rating_rows()
        used = self._sessions_in(rows)
        last = self.latest_fit()
        if last is not None and last["used"] == used:
            return None
        if sum(n >= len(self.ids) for n in used.values()) < \
                self.settings.warmup_participants:
            return None
        t0 = time.perf_counter()
        fit = self._fit(rows, used)
        seconds = time.perf_counter() - t0
        with self.store.writing() as con:
            cur = con.execute("INSERT INTO allocation_fits (at, used, fit, seconds) VALUES "
                              "(?,?,?,?)", (utc_now(), canonical(used), json.dumps(fit),
                                            seconds))
            fit_id = int(cur.lastrowid)
        log.info("allocation fit %d: %d ratings of %d sessions in %.2f s", fit_id,
                 sum(used.values()), len(used), seconds)
        return fit_id

    def _fit(self, rows: list[tuple[str, str, str, str, str]],
             used: dict[str, int]) -> dict[str, Any]:
        """The analysis' fit of exactly the first ``used[session]`` ratings of each session."""
        from .analysis_adapter import allocation_fit_of, loaded_manifest
        from .stats import ratings_frame

        assert self.settings is not None
        taken: Counter[str] = Counter()
        chosen = []
        for r in rows:
            if taken[r[4]] < used.get(r[4], 0):
                taken[r[4]] += 1
                chosen.append(r)
        frame = ratings_frame(chosen, self.study_id)
        loaded = loaded_manifest(self.manifest_bytes, self.manifest_sha256)
        return allocation_fit_of(frame, loaded, n_boot=self.settings.bootstrap, seed=0)

    def latest_fit(self) -> dict[str, Any] | None:
        """The newest fit of this version's ratings (another version's fit plans nothing
        here: its stimuli and its warm-up are its own). Asked at every block request, so
        fits are read newest first, and only the first of this version is parsed whole."""
        owner = self._owner()
        with self.store.reading() as con:
            for r in con.execute("SELECT fit_id, at, used, fit, seconds FROM allocation_fits "
                                 "ORDER BY fit_id DESC"):
                if owner(json.loads(r[2])) == self.manifest_sha256:
                    return _fit_row(r)
        return None

    def fits(self) -> list[dict[str, Any]]:
        """This version's fits, with those whose sessions have all been withdrawn since (no
        version can be told for them; the replay reports them)."""
        owner = self._owner()
        with self.store.reading() as con:
            rows = con.execute("SELECT fit_id, at, used, fit, seconds FROM allocation_fits "
                               "ORDER BY fit_id").fetchall()
        return [_fit_row(r) for r in rows
                if owner(json.loads(r[2])) in (self.manifest_sha256, None)]

    def _owner(self) -> Callable[[dict[str, int]], str | None]:
        """The version a fit belongs to, from the sessions it used (a fit uses the ratings of
        one version only, see :meth:`_rating_rows`); None when all of them were withdrawn."""
        version = {s.session_id: s.manifest_sha256 for s in self.store.sessions()}

        def owner(used: dict[str, int]) -> str | None:
            return next((version[s] for s in used if s in version), None)
        return owner

    # -- issuing blocks ---------------------------------------------------------------
    def issue(self, pid: str, session_id: str, block: int, last: str | None) -> IssuedBlock:
        """Block ``block`` of ``pid``'s session: the one issued before, or a new one."""
        if self.settings is None:
            raise Refused(409, "this study allocates every trial up front (full design); it "
                               "issues no blocks")
        sess = self.store.session_of(pid)
        if sess is None or sess.session_id != session_id:
            raise Refused(409, "upload the session before asking for its next block")
        if sess.manifest_sha256 != self.manifest_sha256:
            raise Refused(409, "the session runs on an earlier version of the study")
        if not 2 <= block <= self.settings.blocks:
            raise Refused(422, f"block {block} is not one of 2..{self.settings.blocks}")
        if last is not None and last not in self.ids:
            raise Refused(422, "last: not a stimulus of this study")
        with self._lock:
            issued = self.issued(session_id)
            if block in issued:
                return issued[block]
            if block != max(issued, default=1) + 1:
                raise Refused(409, f"block {block} asked for before block {block - 1}")
            return self._plan_and_log(pid, session_id, block, last)

    def _plan_and_log(self, pid: str, session_id: str, block: int,
                      last: str | None) -> IssuedBlock:
        assert self.settings is not None
        t0 = time.perf_counter()
        fit = self.latest_fit()
        size = self.settings.trials_per_block(len(self.ids))
        pending = self.pending(fit) if fit is not None else {}
        seed = block_seed(self._session_seed(session_id), block)
        inputs = {"pending": pending, "last": last, "seed": seed, "size": size,
                  "max_per_block": self.settings.max_per_block}
        stimuli = self.plan(fit, inputs)
        bid = block_id(session_id, block, stimuli)
        seconds = time.perf_counter() - t0
        with self.store.writing() as con:
            con.execute(
                "INSERT INTO allocation_blocks (session_id, block, block_id, participant, "
                "issued_at, fit_id, inputs, stimuli, seconds) VALUES (?,?,?,?,?,?,?,?,?)",
                (session_id, block, bid, pid, utc_now(),
                 None if fit is None else fit["fit_id"], canonical(inputs),
                 canonical(stimuli), seconds))
        log.info("block %d of %s issued (fit %s) in %.3f s", block, pid,
                 None if fit is None else fit["fit_id"], seconds)
        return IssuedBlock(block, bid, stimuli)

    def plan(self, fit: dict[str, Any] | None, inputs: dict[str, Any]) -> list[str]:
        """A block's stimuli in order, from a fit (None: uniform) and the logged inputs."""
        size = int(inputs["size"])
        if fit is None:
            counts = uniform_counts(self.ids, size, int(inputs["seed"]), last=inputs["last"])
        else:
            from .analysis_adapter import plan_counts

            counts = plan_counts(fit["fit"], size, inputs["pending"],
                                 int(inputs["max_per_block"]), last=inputs["last"])
        trials = order_trials(self.items, counts, int(inputs["seed"]), last=inputs["last"])
        return [t.stimulus for t in trials]

    def pending(self, fit: dict[str, Any]) -> dict[str, int]:
        """Ratings per stimulus the fit has not seen but will: those arrived since, and the
        still unanswered trials of open sessions (their plans and issued blocks)."""
        rows = self._rating_rows()
        used = fit["used"]
        seen: Counter[str] = Counter()
        taken: Counter[str] = Counter()
        now: dict[str, Counter[str]] = {}
        for _, _, _, body, sid in rows:
            stimulus = json.loads(body).get("row", {}).get("stimulus")
            now.setdefault(sid, Counter())[stimulus] += 1
            if taken[sid] < used.get(sid, 0):
                taken[sid] += 1
                seen[stimulus] += 1
        out: Counter[str] = Counter()
        cutoff = datetime.now(UTC) - timedelta(seconds=PENDING_EXPIRY_S)
        for s in self.store.sessions():
            if s.manifest_sha256 != self.manifest_sha256:
                continue
            rated = now.get(s.session_id, Counter())
            if s.finished_at is None and _received_after(s.last_received, cutoff):
                planned = Counter(self.ids)  # block 1: every stimulus once
                for b in self.issued(s.session_id).values():
                    planned.update(b.stimuli)
                out.update({k: max(planned[k], rated[k]) for k in planned | rated})
            else:
                out.update(rated)
        return {k: int(out[k] - seen[k]) for k in self.ids if out[k] - seen[k] > 0}

    def _session_seed(self, session_id: str) -> int:
        first = self.store.entries(session_id, 0, 1)
        return int(json.loads(first[0].body)["header"]["seed"])

    def issued(self, session_id: str) -> dict[int, IssuedBlock]:
        with self.store.reading() as con:
            rows = con.execute("SELECT block, block_id, stimuli FROM allocation_blocks WHERE "
                               "session_id=? ORDER BY block", (session_id,)).fetchall()
        return {int(r[0]): IssuedBlock(int(r[0]), str(r[1]), json.loads(r[2])) for r in rows}

    def log_rows(self) -> list[dict[str, Any]]:
        """Every issued block with its inputs, in issue order (for the audit)."""
        with self.store.reading() as con:
            rows = con.execute(
                "SELECT b.session_id, b.block, b.block_id, b.participant, b.issued_at, "
                "b.fit_id, b.inputs, b.stimuli, b.seconds FROM allocation_blocks b JOIN "
                "sessions s ON s.session_id = b.session_id WHERE s.manifest_sha256 = ? "
                "ORDER BY b.issued_at, b.session_id, b.block", (self.manifest_sha256,)
            ).fetchall()
        return [{"session_id": r[0], "block": r[1], "block_id": r[2], "participant": r[3],
                 "issued_at": r[4], "fit_id": r[5], "inputs": json.loads(r[6]),
                 "stimuli": json.loads(r[7]), "seconds": r[8]} for r in rows]

    # -- checking uploads -------------------------------------------------------------
    def check_entries(self, pid: str, session_id: str, manifest_sha256: str | None,
                      entries: list[Any]) -> str | None:
        """Why these uploaded entries contradict the allocation (None: they fit): block 1
        must be the session's seeded plan (every stimulus once), a later block exactly the
        block this server issued for it."""
        if self.settings is None or manifest_sha256 != self.manifest_sha256:
            return None
        for e in entries:
            if e.kind == "session":
                header, plan = e.body.get("header") or {}, e.body.get("plan") or []
                expected = order_trials(self.items, dict.fromkeys(self.ids, 1),
                                        int(header.get("seed", -1)))
                if [p[1] for p in plan] != [t.stimulus for t in expected]:
                    return ("block 1 is not the plan this study gives the session's seed "
                            "(every stimulus once, in the seeded order)")
            elif e.kind == "block":
                body = e.body
                issued = self.issued(session_id).get(int(body.get("block", -1)))
                stimuli = [t[0] for t in body.get("trials") or []]
                if issued is None or body.get("issued_by") != "server":
                    return f"block {body.get('block')} was not issued by this server"
                if body.get("id") != issued.block_id or stimuli != issued.stimuli:
                    return (f"block {body.get('block')} differs from the block this server "
                            "issued")
                items = {it.id: it for it in self.items}
                if any(t[1] != items[t[0]].reference or bool(t[3]) !=
                       items[t[0]].is_hidden_reference for t in body["trials"]):
                    return f"block {body.get('block')} names wrong references"
        return None

    # -- audit ------------------------------------------------------------------------
    def replay(self) -> list[str]:
        """Refit every logged fit from the stored ratings and re-plan every logged block
        from its logged inputs; what differs (empty: the allocation replays identically)."""
        problems: list[str] = []
        fits = {f["fit_id"]: f for f in self.fits()}
        rows = self._rating_rows()
        for fit_id, f in fits.items():
            have = self._sessions_in(rows)
            missing = [s for s, n in f["used"].items() if have.get(s, 0) < n]
            if missing:
                problems.append(f"fit {fit_id}: the ratings of {len(missing)} session(s) it "
                                "used are no longer stored (withdrawn)")
                continue
            again = self._fit(rows, f["used"])
            if canonical(again) != canonical(f["fit"]):
                problems.append(f"fit {fit_id}: refitting its ratings gives other numbers")
        for b in self.log_rows():
            fit = fits.get(b["fit_id"]) if b["fit_id"] is not None else None
            if self.plan(fit, b["inputs"]) != b["stimuli"]:
                problems.append(f"block {b['block']} of {b['participant']}: re-planning it "
                                "from its inputs gives another block")
        return problems


def _received_after(stamp: str, cutoff: datetime) -> bool:
    """Whether the ISO 8601 time ``stamp`` (as the store writes it) is after ``cutoff``."""
    try:
        return datetime.fromisoformat(stamp.replace("Z", "+00:00")) > cutoff
    except ValueError:
        return False


def _warm_up() -> None:
    """Import the research stack on the worker thread, not in the first block request."""
    from .analysis_adapter import warm_up

    warm_up()


def _fit_row(row: Any) -> dict[str, Any]:
    return {"fit_id": int(row[0]), "at": row[1], "used": json.loads(row[2]),
            "fit": json.loads(row[3]), "seconds": float(row[4])}
