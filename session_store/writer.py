"""Writing a session file: creation with its plan, one committed transaction per rating.

Both the participant's app and the simulated participants write through :class:`SessionStore`.
Every write transaction is followed by a WAL checkpoint, so the main ``.sqlite`` file holds
every committed rating on its own: a participant who sends only that file after a crash
loses nothing.

A checkpoint that fails for a reason other than a busy reader (a full disk, an I/O error)
can leave the main file consistent only together with its ``-wal``; it is never reported as
a saved rating: the write raises :class:`StudyError` saying which files hold the ratings.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sqlite3
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from .chain import canonical, normalise_row, row_hash, sha256_text
from .errors import StudyError
from .ids import check_participant_id
from .mutations import apply as apply_change
from .mutations import create_tables
from .outbox import append as append_to_outbox
from .outbox import has_outbox
from .reader import SessionRecord, read_header, record_from, session_info
from .records import PlannedTrial, SessionInfo, TrialResult, utc_now
from .schema import CHAINED, PANEL_DDL, connect, open_existing, wal_pending_bytes
from .sqlite_errors import is_busy, is_disk_full, is_io_error, roll_back

log = logging.getLogger(__name__)

_FINITE_FIELDS = ("rating", "rt_ms", "ms_on_reference", "ms_on_test", "slider_first_move_ms",
                  "max_flip_interval_ms")


def _check_finite(name: str, value: float | None) -> None:
    if value is not None and not math.isfinite(value):
        raise StudyError(f"trial result {name} must be a finite number, got {value}")


class SessionStore:
    """Writer (and reader) of one session file. Use :meth:`create` or :meth:`open`."""

    def __init__(self, con: sqlite3.Connection, path: Path, *, durable: bool = True) -> None:
        self._con = con
        self.path = path
        self.durable = durable
        self.clock: Callable[[], str] = utc_now
        """The time each change is stamped with; a simulation sets its own made-up clock."""
        if not durable:  # simulated participants: no fsync per rating, one checkpoint at close
            self._con.execute("PRAGMA synchronous=OFF")
        self._con.execute("PRAGMA busy_timeout=5000")  # the upload client writes acks
        self._outbox = has_outbox(con)
        self._session_id = str(read_header(con)["session_id"])
        if not con.execute("PRAGMA query_only").fetchone()[0]:
            for stmt in PANEL_DDL.split(";"):  # a file older than the panel tables
                if stmt.strip():
                    con.execute(stmt)

    # -- construction -----------------------------------------------------------------
    @classmethod
    def create(
        cls,
        path: str | Path,
        *,
        participant: str,
        study_id: str,
        manifest_sha256: str | None,
        seed: int,
        app_version: str,
        plan: Sequence[PlannedTrial],
        settings: dict[str, Any] | None = None,
        session_id: str | None = None,
        created_at: str | None = None,
        durable: bool = True,
        preflight: Sequence[dict[str, Any]] | None = None,
        preflight_skipped: bool = False,
        events: Sequence[tuple[str, dict[str, Any]]] = (),
    ) -> SessionStore:
        """Create a new session file with its trial order; refuses to overwrite a file.

        The file appears under its real name only once the plan is stored, so a crash during
        creation leaves no half-made session behind. ``preflight`` (results, with
        ``preflight_skipped``) and ``events`` (kind, details; e.g. the consent) are stored
        in the same transaction, so a session never exists without them. ``durable=False``
        (simulated participants only) skips the per-rating fsync and checkpoint; the file is
        complete once closed.
        """
        path = Path(path)
        check_participant_id(participant)
        if path.exists():
            raise StudyError(
                f"session file {path} already exists; open it to resume, or choose another "
                "participant id"
            )
        if not plan:
            raise StudyError("the trial plan is empty: the study has no stimuli to rate")
        if [p.index for p in plan] != list(range(len(plan))):
            raise StudyError("plan indices must be 0, 1, 2, ... in order")
        if path.parent.exists() and not path.parent.is_dir():
            raise StudyError(f"{path.parent} is a file, not a folder for session files; "
                             "choose another sessions folder")
        # owner-only where made here: a session holds a person's answers (a shared lab PC)
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        created_at = created_at or utc_now()
        if session_id is None:
            session_id = sha256_text(canonical([study_id, participant, seed, created_at]))[:16]
        header = {
            "session_id": session_id, "participant": participant, "study_id": study_id,
            "manifest_sha256": manifest_sha256, "seed": int(seed), "app_version": app_version,
            "created_at": created_at,
        }
        body = {"header": header, "settings": settings or {},
                "plan": [[p.index, p.stimulus, p.reference, int(p.repetition),
                          int(p.is_hidden_reference)] for p in plan]}
        tmp = path.with_name(path.name + ".creating")
        tmp.unlink(missing_ok=True)
        changes = [("session", body), *_first_changes(preflight, preflight_skipped, events)]
        tmp.touch(mode=0o600)  # SQLite gives its -wal and -shm the database file's mode
        con = connect(tmp, readonly=False)
        try:
            con.execute("BEGIN IMMEDIATE")
            create_tables(con)
            for kind, change in changes:
                apply_change(con, kind, change)
                append_to_outbox(con, kind, change, session_id)
            con.execute("COMMIT")
            con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            con.close()
        except BaseException as exc:
            con.close()
            for suffix in ("", "-wal", "-shm"):
                Path(str(tmp) + suffix).unlink(missing_ok=True)
            if isinstance(exc, sqlite3.Error):
                raise StudyError(f"could not create the session file {path} ({exc}); "
                                 f"{_space_advice(exc)}") from None
            raise
        for suffix in ("-wal", "-shm"):
            Path(str(tmp) + suffix).unlink(missing_ok=True)
        tmp.replace(path)
        return cls.open(path, durable=durable)

    @classmethod
    def open(cls, path: str | Path, *, durable: bool = True) -> SessionStore:
        """Open an existing session file for resuming (read-write)."""
        path = Path(path)
        con = open_existing(path, readonly=False)
        return cls(con, path, durable=durable)

    def close(self) -> None:
        """Checkpoint the WAL into the main file and close. A checkpoint that fails (a full
        disk) is a :class:`StudyError` after the connection is closed: the ``-wal`` then
        stays beside the file and holds ratings the main file lacks, which the participant
        must be told."""
        try:
            self._checkpoint(always=True)
        finally:
            self._con.close()

    def save_to_file(self) -> None:
        """Checkpoint the WAL into the main file now, so that the file alone holds every
        rating: the player calls it before its end screen, which must say so when it fails
        (the ``-wal`` then holds ratings the main file lacks). Raises :class:`StudyError`
        then; a busy reader only postpones it to :meth:`close`."""
        self._checkpoint(always=True)

    def __enter__(self) -> SessionStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reading ----------------------------------------------------------------------
    @property
    def info(self) -> SessionInfo:
        kinds = {r[0] for r in self._con.execute("SELECT DISTINCT kind FROM events")}
        return session_info(self.path, read_header(self._con), kinds)

    @property
    def is_finished(self) -> bool:
        return self.info.finished_at is not None

    def plan(self) -> list[PlannedTrial]:
        """The whole trial order, including trials re-queued at the end."""
        return self.snapshot().plan

    def pending(self) -> list[PlannedTrial]:
        """Unanswered trials in plan order (trials superseded by a re-queue left out)."""
        rows = self._con.execute(
            "SELECT * FROM plan p WHERE NOT EXISTS (SELECT 1 FROM ratings r WHERE r.trial=p.idx)"
            " AND NOT EXISTS (SELECT 1 FROM plan q WHERE q.requeue_of=p.idx) ORDER BY idx"
        ).fetchall()
        return [PlannedTrial(r["idx"], r["stimulus"], r["reference"], r["repetition"],
                             bool(r["is_hidden_reference"]), r["requeue_of"]) for r in rows]

    def next_trial(self) -> PlannedTrial | None:
        """The first unanswered trial, or None when every trial is answered."""
        pending = self.pending()
        return pending[0] if pending else None

    def progress(self) -> tuple[int, int]:
        """(answered trials, trials to answer in total), re-queued trials counted once."""
        answered = self._con.execute("SELECT count(*) FROM ratings").fetchone()[0]
        return int(answered), int(answered) + len(self.pending())

    def snapshot(self) -> SessionRecord:
        """Everything in the file, from one snapshot (see :func:`read_session`)."""
        return record_from(self._con, self.path)

    def ratings(self) -> list[dict[str, Any]]:
        """The tidy ratings rows of this session; a broken chain is a :class:`StudyError`."""
        rec = self.snapshot()
        if rec.problems:
            raise StudyError("; ".join(str(p) for p in rec.problems))
        return rec.ratings

    def presentations(self) -> list[dict[str, Any]]:
        """Presentation logs of every trial attempt, in order."""
        return self.snapshot().presentations

    def events(self) -> list[dict[str, Any]]:
        return self.snapshot().events

    # -- writing ----------------------------------------------------------------------
    @contextlib.contextmanager
    def _transaction(self) -> Iterator[None]:
        """``BEGIN IMMEDIATE`` ... ``COMMIT`` (``ROLLBACK`` on error), then a checkpoint so the
        main file holds what was committed. A failed write (full disk, I/O error, file held
        by another program) is a :class:`StudyError` saying what was kept, never a raw
        sqlite3 error."""
        try:
            self._con.execute("BEGIN IMMEDIATE")
        except sqlite3.Error as exc:
            raise StudyError(self._write_failure(exc, committed=False)) from None
        try:
            yield
            self._con.execute("COMMIT")
        except BaseException as exc:
            roll_back(self._con)
            if isinstance(exc, sqlite3.Error):
                raise StudyError(self._write_failure(exc, committed=False)) from None
            raise
        self._checkpoint()


    def _checkpoint(self, *, always: bool = False) -> None:
        """Copy the WAL into the main file. Busy readers only postpone it (the next one
        catches up, and the WAL is the file's to read until then); any other failure means
        the main file may now be readable only together with its ``-wal``: a
        :class:`StudyError` that says so."""
        if not (self.durable or always):
            return
        try:
            busy, frames, done = self._con.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()
        except sqlite3.Error as exc:
            if not is_busy(exc):
                raise StudyError(self._write_failure(exc, committed=True)) from None
            log.debug("checkpoint of %s postponed: %s", self.path, exc)
            return
        if busy:
            log.debug("checkpoint of %s incomplete (%s of %s frames)", self.path, done, frames)

    def _ratings_so_far(self) -> int | None:
        """Committed ratings (None when the file cannot even be read any more)."""
        try:
            return int(self._con.execute("SELECT n_ratings FROM session").fetchone()[0])
        except (sqlite3.Error, TypeError, ValueError):
            return None

    def _write_failure(self, exc: sqlite3.Error, *, committed: bool) -> str:
        """The one-line message of a failed write: what failed, which files hold the ratings
        given so far, and what to do (free space and run again; never send the main file
        without its ``-wal`` when one is there)."""
        name = self.path.name
        if is_busy(exc):
            return (f"the session file {name} is held by another program ({exc}); close "
                    "other copies of cgvq-study and run the same command again")
        n = self._ratings_so_far()
        told = ("your ratings so far" if n is None else
                f"your {n} rating(s) so far (up to trial {n})")
        what = ("the disk is full" if is_disk_full(exc)
                else f"the disk could not be written ({exc})" if is_io_error(exc)
                else f"the session file could not be written ({exc})")
        lost = "" if committed else "; the rating on screen was not saved"
        if committed or wal_pending_bytes(self.path) > 0:
            kept = (f"{told} are kept in the two files {name} and {name}-wal together in "
                    f"{self.path.parent}: do not send {name} alone and do not delete "
                    f"{name}-wal; {_space_advice(exc)} (that merges them into {name}); if "
                    "you cannot, send both files to the experimenter")
        else:
            kept = f"{told} are kept in {name} in {self.path.parent}; {_space_advice(exc)}"
        return f"{what} while saving to {name}{lost}: {kept}"

    def _require_open(self) -> None:
        if self.is_finished:
            raise StudyError(
                f"session {self.path} is finished; it accepts no new ratings. Send the file "
                "back as it is, or start a new session with another participant id"
            )

    def _check_next(self, trial_index: int) -> PlannedTrial:
        self._require_open()
        nxt = self.next_trial()
        if nxt is None:
            raise StudyError(f"session {self.path}: every trial is already answered")
        if trial_index != nxt.index:
            raise StudyError(
                f"session {self.path}: trial {trial_index} is not the next unanswered trial "
                f"({nxt.index}); ratings are recorded in plan order, never twice"
            )
        return nxt

    def _change(self, kind: str, body: dict[str, Any]) -> None:
        """Apply one change and log it in the outbox, in one committed transaction."""
        with self._transaction():
            apply_change(self._con, kind, body)
            if self._outbox:
                append_to_outbox(self._con, kind, body, self._session_id)

    def add_block(self, block: int, block_id: str, trials: Sequence[tuple[str, str, int, bool]],
                  *, issued_by: str) -> list[PlannedTrial]:
        """Append block ``block`` (2, 3, ...) of an adaptive study to the plan: its trials as
        (stimulus, reference, repetition, is_hidden_reference), as issued by the study server
        (``issued_by`` "server") or planned by the app without one ("session"); one committed
        transaction, in the hash-chained change log."""
        self._require_open()
        self._change("block", {"at": self.clock(), "block": int(block), "id": str(block_id),
                               "issued_by": issued_by,
                               "trials": [[s, r, int(k), bool(h)] for s, r, k, h in trials]})
        return self.plan()[-len(trials):]

    def blocks_done(self) -> int:
        """Blocks in the plan so far (1 for the session's first plan)."""
        return 1 + int(self._con.execute(
            "SELECT count(*) FROM events WHERE kind='block'").fetchone()[0])

    def log_event(self, kind: str, **details: Any) -> None:
        """Append a session event (one committed transaction)."""
        self._change("event", {"at": self.clock(), "kind": kind, "details": details})

    def mark_started(self, *, display: dict[str, Any] | None = None) -> None:
        """Record that the participant began (or resumed) the session, with the display."""
        self._require_open()
        self._change("start", {"at": self.clock(), "display": display})

    def save_preflight(self, results: Iterable[dict[str, Any]], *, skipped: bool) -> None:
        """Store the pre-flight results (each a dict with at least name, ok, message)."""
        self._change("preflight", {"at": self.clock(), "results": list(results),
                                   "skipped": bool(skipped)})

    def record(self, trial_index: int, result: TrialResult) -> str:
        """Store the rating of the next unanswered trial; one committed transaction.

        Returns the row's hash. Raises :class:`StudyError` for a finished session, a trial out
        of order or an already answered one (no duplicates).
        """
        for name in _FINITE_FIELDS:
            _check_finite(name, getattr(result, name))
        trial = self._check_next(trial_index)
        header = read_header(self._con)
        row = normalise_row({
            "seq": int(header["n_ratings"]) + 1,
            "trial": trial.index,
            "stimulus": trial.stimulus,
            "reference": trial.reference,
            "repetition": trial.repetition,
            "is_hidden_reference": int(trial.is_hidden_reference),
            "rating": result.rating,
            "rt_ms": result.rt_ms,
            "n_toggles": result.n_toggles,
            "ms_on_reference": result.ms_on_reference,
            "ms_on_test": result.ms_on_test,
            "slider_first_move_ms": result.slider_first_move_ms,
            "frames_presented": result.frames_presented,
            "dropped_frames": result.dropped_frames,
            "max_flip_interval_ms": result.max_flip_interval_ms,
            "switch_latencies_ms": canonical([float(x) for x in result.switch_latencies_ms]),
            "presented_at": result.presented_at,
            "answered_at": result.answered_at or self.clock(),
            "app_version": header["app_version"],
            "prev_hash": header["head_hash"],
        })
        row["row_hash"] = row_hash(row)
        self._change("rating", {"row": {c: row[c] for c in (*CHAINED, "row_hash")},
                                "presentation": _presentation(result, self.clock())})
        return row["row_hash"]

    def requeue(self, trial_index: int, result: TrialResult, reason: str) -> PlannedTrial:
        """Discard this attempt of the next trial (e.g. too many dropped frames) and append the
        same stimulus and repetition at the end of the plan; one committed transaction."""
        trial = self._check_next(trial_index)
        new_idx = int(self._con.execute("SELECT max(idx) + 1 FROM plan").fetchone()[0])
        self._change("requeue", {"trial": trial.index, "new_idx": new_idx,
                                 "presentation": _presentation(result, self.clock(),
                                                               reason=reason)})
        return PlannedTrial(new_idx, trial.stimulus, trial.reference, trial.repetition,
                            trial.is_hidden_reference, trial.index)

    def record_answer(self, questionnaire: str, question: str, value: Any, *, page: int,
                      ms: float | None = None) -> None:
        """Store one confirmed answer (already checked against its question by the caller,
        see ``stimuli_manifests.panel.check_answer``); one committed transaction, so a crash
        loses at most the answer being given. Allowed after the last trial (the post-study
        survey), refused once the participant withdrew."""
        self._change("answer", {"at": self.clock(), "questionnaire": questionnaire,
                                "question": question, "value": value, "page": int(page),
                                "ms": None if ms is None else float(ms)})

    def record_screening(self, test: str, outcome: str, result: dict[str, Any]) -> None:
        """Store the result of one vision check (``outcome`` passed, failed, inconclusive)."""
        self._change("screening", {"at": self.clock(), "test": test, "outcome": outcome,
                                   "result": result})

    def finish(self, *, allow_incomplete: bool = False) -> None:
        """Close the session for good: afterwards it refuses new ratings."""
        self._require_open()
        pending = len(self.pending())
        if pending and not allow_incomplete:
            raise StudyError(
                f"session {self.path} still has {pending} unanswered trial(s); it cannot be "
                "finished yet"
            )
        self._change("finish", {"at": self.clock(), "unanswered": pending})

    def withdraw(self, reason: str = "participant withdrew") -> None:
        """The participant withdraws: the session is closed for good and marked withdrawn
        (its ratings stay in the file; the experimenter decides what to do with them)."""
        self._require_open()
        answered, total = self.progress()
        self._change("withdrawn", {"at": self.clock(), "reason": reason, "answered": answered,
                                   "total": total})


def _space_advice(exc: sqlite3.Error) -> str:
    """What the participant can do about a failed write."""
    if is_disk_full(exc):
        return "free some disk space and run the same command again"
    return "check the disk (is it still connected?) and run the same command again"


def _first_changes(preflight: Sequence[dict[str, Any]] | None, skipped: bool,
                   events: Sequence[tuple[str, dict[str, Any]]]
                   ) -> list[tuple[str, dict[str, Any]]]:
    """The changes stored with a new session in its creation transaction (the same bodies
    :meth:`SessionStore.save_preflight` and :meth:`SessionStore.log_event` write)."""
    changes: list[tuple[str, dict[str, Any]]] = []
    if preflight is not None:
        changes.append(("preflight", {"at": utc_now(), "results": list(preflight),
                                      "skipped": bool(skipped)}))
    changes += [("event", {"at": utc_now(), "kind": kind, "details": details})
                for kind, details in events]
    return changes


def _presentation(result: TrialResult, logged_at: str, **extra: Any) -> dict[str, Any]:
    """The presentation log of one trial attempt (what a trial measured, beyond the rating)."""
    details = {k: v for k, v in asdict(result).items() if k != "details"}
    details.update(result.details)
    details.update(extra)
    return {"details": details, "logged_at": logged_at}
