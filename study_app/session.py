"""The session store: one crash-safe, hash-chained SQLite file per participant session.

Both the participant's app and the simulated participants write through this module, and the
analysis reads through it, so it imports only the standard library (no Pygame, no OpenGL).

Schema (``cgvq-session/1``)
---------------------------
``meta(key TEXT PRIMARY KEY, value TEXT)``
    ``schema`` = :data:`SCHEMA_VERSION`. A file whose major version differs is refused.
``session`` (exactly one row)
    ``session_id, participant, study_id, manifest_sha256, seed, app_version, created_at``
    (these and the original plan form the *genesis* of the hash chain), ``settings`` (JSON:
    protocol values in force), ``display`` (JSON: screen, refresh rate, vsync), ``preflight``
    (JSON: list of check results), ``preflight_skipped`` (0/1), ``started_at``,
    ``finished_at`` (NULL while open), ``n_ratings`` and ``head_hash`` (the last rating row's
    hash, updated in the same transaction as the row: a removed tail is detected).
``plan(idx INTEGER PRIMARY KEY, stimulus, reference, repetition, is_hidden_reference, requeue_of)``
    The trial order, stored before the first trial. ``requeue_of`` is NULL for planned trials
    and names the superseded trial for a trial re-queued (at the end) after too many dropped
    frames.
``ratings`` (one row per answered trial, ``trial`` unique)
    ``seq`` (1, 2, ... in answer order), ``trial`` (the plan index), ``stimulus, reference,
    repetition, is_hidden_reference, rating, rt_ms, n_toggles, ms_on_reference, ms_on_test,
    slider_first_move_ms, frames_presented, dropped_frames, max_flip_interval_ms,
    switch_latencies_ms`` (JSON list), ``presented_at`` (ISO 8601 UTC), ``answered_at``,
    ``app_version``, ``prev_hash``, ``row_hash``. ``row_hash = sha256(prev_hash + canonical
    JSON of every other column)``; the first row's ``prev_hash`` is the sha256 of the canonical
    session header and original plan, so editing the participant, the plan or any rating
    breaks the chain.
``presentations(id, trial, outcome, details JSON, logged_at)``
    Per trial attempt: flip-timing summary, toggles, switch latencies; ``outcome`` is
    ``rated`` or ``requeued``.
``events(id, at, kind, details JSON)``
    Session events (start, resume, pause, pre-flight skipped, finish).

SQLite runs in WAL mode with ``synchronous=FULL``; every rating is one committed transaction,
so killing the process at any moment loses at most the trial on screen.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import logging
import math
import sqlite3
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from .errors import StudyError

log = logging.getLogger(__name__)

SCHEMA_NAME = "cgvq-session"
SCHEMA_MAJOR = 1
SCHEMA_VERSION = f"{SCHEMA_NAME}/{SCHEMA_MAJOR}"

RATINGS_COLUMNS: tuple[str, ...] = (
    "study",
    "session",
    "participant",
    "trial",
    "stimulus",
    "reference",
    "repetition",
    "is_hidden_reference",
    "rating",
    "rt_ms",
    "n_toggles",
    "ms_on_reference",
    "ms_on_test",
    "dropped_frames",
    "presented_at",
    "app_version",
)

# Columns of the ratings table covered by the hash (everything except row_hash itself).
_CHAINED = (
    "seq",
    "trial",
    "stimulus",
    "reference",
    "repetition",
    "is_hidden_reference",
    "rating",
    "rt_ms",
    "n_toggles",
    "ms_on_reference",
    "ms_on_test",
    "slider_first_move_ms",
    "frames_presented",
    "dropped_frames",
    "max_flip_interval_ms",
    "switch_latencies_ms",
    "presented_at",
    "answered_at",
    "app_version",
    "prev_hash",
)
_INT_COLS = {
    "seq", "trial", "repetition", "is_hidden_reference", "n_toggles", "frames_presented",
    "dropped_frames",
}
_REAL_COLS = {
    "rating", "rt_ms", "ms_on_reference", "ms_on_test", "slider_first_move_ms",
    "max_flip_interval_ms",
}

_DDL = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE session (
    session_id TEXT NOT NULL, participant TEXT NOT NULL, study_id TEXT NOT NULL,
    manifest_sha256 TEXT, seed INTEGER NOT NULL, app_version TEXT NOT NULL,
    created_at TEXT NOT NULL, settings TEXT NOT NULL DEFAULT '{}',
    display TEXT NOT NULL DEFAULT '{}', preflight TEXT NOT NULL DEFAULT '[]',
    preflight_skipped INTEGER NOT NULL DEFAULT 0, started_at TEXT, finished_at TEXT,
    n_ratings INTEGER NOT NULL DEFAULT 0, head_hash TEXT NOT NULL
);
CREATE TABLE plan (
    idx INTEGER PRIMARY KEY, stimulus TEXT NOT NULL, reference TEXT NOT NULL,
    repetition INTEGER NOT NULL, is_hidden_reference INTEGER NOT NULL,
    requeue_of INTEGER REFERENCES plan(idx)
);
CREATE TABLE ratings (
    seq INTEGER PRIMARY KEY, trial INTEGER NOT NULL UNIQUE REFERENCES plan(idx),
    stimulus TEXT NOT NULL, reference TEXT NOT NULL, repetition INTEGER NOT NULL,
    is_hidden_reference INTEGER NOT NULL, rating REAL NOT NULL, rt_ms REAL NOT NULL,
    n_toggles INTEGER NOT NULL, ms_on_reference REAL NOT NULL, ms_on_test REAL NOT NULL,
    slider_first_move_ms REAL, frames_presented INTEGER NOT NULL,
    dropped_frames INTEGER NOT NULL, max_flip_interval_ms REAL NOT NULL,
    switch_latencies_ms TEXT NOT NULL, presented_at TEXT NOT NULL, answered_at TEXT NOT NULL,
    app_version TEXT NOT NULL, prev_hash TEXT NOT NULL, row_hash TEXT NOT NULL
);
CREATE TABLE presentations (
    id INTEGER PRIMARY KEY AUTOINCREMENT, trial INTEGER NOT NULL, outcome TEXT NOT NULL,
    details TEXT NOT NULL, logged_at TEXT NOT NULL
);
CREATE TABLE events (
    id INTEGER PRIMARY KEY AUTOINCREMENT, at TEXT NOT NULL, kind TEXT NOT NULL,
    details TEXT NOT NULL DEFAULT '{}'
);
"""


def utc_now() -> str:
    """The current time as ISO 8601 UTC with milliseconds (``2026-01-01T12:00:00.123Z``)."""
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=False)


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class PlannedTrial:
    """One entry of the trial order: which stimulus, which repetition, at which position."""

    index: int
    stimulus: str
    reference: str
    repetition: int
    is_hidden_reference: bool
    requeue_of: int | None = None


@dataclass
class TrialResult:
    """What one answered trial produced (times in milliseconds from the trial's first frame)."""

    rating: float
    rt_ms: float
    n_toggles: int
    ms_on_reference: float
    ms_on_test: float
    presented_at: str
    slider_first_move_ms: float | None = None
    frames_presented: int = 0
    dropped_frames: int = 0
    max_flip_interval_ms: float = 0.0
    switch_latencies_ms: list[float] = field(default_factory=list)
    answered_at: str | None = None
    details: dict[str, Any] = field(default_factory=dict)
    """Free presentation-log details (flip statistics, toggle times, vsync) kept per attempt."""


@dataclass(frozen=True)
class SessionProblem:
    """Something wrong with a session file; ``row`` is the trial index when one is concerned."""

    path: Path
    row: int | None
    message: str

    def __str__(self) -> str:
        where = f" (trial {self.row})" if self.row is not None else ""
        return f"{self.path}{where}: {self.message}"


@dataclass(frozen=True)
class SessionInfo:
    """The session record (header) of a session file."""

    session_id: str
    participant: str
    study_id: str
    manifest_sha256: str | None
    seed: int
    app_version: str
    created_at: str
    settings: dict[str, Any]
    display: dict[str, Any]
    preflight: list[dict[str, Any]]
    preflight_skipped: bool
    started_at: str | None
    finished_at: str | None


def _genesis(header: dict[str, Any], plan: Sequence[PlannedTrial]) -> str:
    body = {
        "header": {k: header[k] for k in (
            "session_id", "participant", "study_id", "manifest_sha256", "seed", "app_version",
            "created_at")},
        "plan": [[p.index, p.stimulus, p.reference, p.repetition, int(p.is_hidden_reference)]
                 for p in plan],
    }
    return _sha(SCHEMA_VERSION + _canonical(body))


def _row_hash(row: dict[str, Any]) -> str:
    content = {k: row[k] for k in _CHAINED if k != "prev_hash"}
    return _sha(row["prev_hash"] + _canonical(content))


def _normalise_row(row: dict[str, Any]) -> dict[str, Any]:
    """Coerce values to what SQLite returns, so the hash computed on write matches on read."""
    out = dict(row)
    for k in _INT_COLS:
        out[k] = int(out[k])
    for k in _REAL_COLS:
        if out[k] is not None:
            out[k] = float(out[k])
    return out


def _check_finite(name: str, value: float | None) -> None:
    if value is not None and not math.isfinite(value):
        raise StudyError(f"trial result {name} must be a finite number, got {value}")


def _connect(path: Path, *, readonly: bool) -> sqlite3.Connection:
    if readonly:
        uri = f"{path.resolve().as_uri()}?mode=ro"
        try:
            con = sqlite3.connect(uri, uri=True, isolation_level=None)
            con.execute("SELECT count(*) FROM sqlite_master").fetchone()
        except sqlite3.OperationalError:
            # Read-only media or folder: read without the WAL side files.
            con = sqlite3.connect(f"{path.resolve().as_uri()}?immutable=1", uri=True,
                                  isolation_level=None)
    else:
        con = sqlite3.connect(str(path), isolation_level=None)
        con.execute("PRAGMA journal_mode=WAL")
        con.execute("PRAGMA synchronous=FULL")
        con.execute("PRAGMA foreign_keys=ON")
    con.row_factory = sqlite3.Row
    return con


def _check_schema(con: sqlite3.Connection, path: Path) -> None:
    try:
        row = con.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
    except sqlite3.DatabaseError:
        raise StudyError(
            f"{path} is not a cgvq-study session file (no session schema found); pass the "
            "<participant>.sqlite file written by 'cgvq-study run' or 'simulate'"
        ) from None
    if row is None:
        raise StudyError(f"{path} is not a cgvq-study session file (schema version missing)")
    name, _, major = str(row[0]).partition("/")
    if name != SCHEMA_NAME or not major.isdigit():
        raise StudyError(f"{path}: unknown session schema {row[0]!r} (expected {SCHEMA_VERSION})")
    if int(major) != SCHEMA_MAJOR:
        raise StudyError(
            f"{path}: session schema {row[0]!r} is not supported by this toolkit (it reads "
            f"{SCHEMA_VERSION}); use the toolkit version that wrote the file or upgrade"
        )


def _open_existing(path: Path, *, readonly: bool) -> sqlite3.Connection:
    path = Path(path)
    if not path.is_file():
        raise StudyError(f"session file not found: {path}")
    try:
        con = _connect(path, readonly=readonly)
    except sqlite3.DatabaseError as exc:
        raise StudyError(f"{path} is not a readable SQLite session file ({exc})") from None
    try:
        _check_schema(con, path)
    except StudyError:
        con.close()
        raise
    return con


def _read_header(con: sqlite3.Connection) -> dict[str, Any]:
    row = con.execute("SELECT * FROM session").fetchone()
    if row is None:
        raise sqlite3.DatabaseError("session record missing")
    return dict(row)


def _read_plan(con: sqlite3.Connection) -> list[PlannedTrial]:
    return [
        PlannedTrial(r["idx"], r["stimulus"], r["reference"], r["repetition"],
                     bool(r["is_hidden_reference"]), r["requeue_of"])
        for r in con.execute("SELECT * FROM plan ORDER BY idx")
    ]


def _info(header: dict[str, Any]) -> SessionInfo:
    return SessionInfo(
        session_id=header["session_id"],
        participant=header["participant"],
        study_id=header["study_id"],
        manifest_sha256=header["manifest_sha256"],
        seed=int(header["seed"]),
        app_version=header["app_version"],
        created_at=header["created_at"],
        settings=json.loads(header["settings"] or "{}"),
        display=json.loads(header["display"] or "{}"),
        preflight=json.loads(header["preflight"] or "[]"),
        preflight_skipped=bool(header["preflight_skipped"]),
        started_at=header["started_at"],
        finished_at=header["finished_at"],
    )


class SessionStore:
    """Writer (and reader) of one session file. Use :meth:`create` or :meth:`open`."""

    def __init__(self, con: sqlite3.Connection, path: Path) -> None:
        self._con = con
        self.path = path

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
    ) -> SessionStore:
        """Create a new session file with its trial order; refuses to overwrite a file."""
        path = Path(path)
        if path.exists():
            raise StudyError(
                f"session file {path} already exists; open it to resume, or choose another "
                "participant id"
            )
        if not participant:
            raise StudyError("participant id must not be empty")
        if not plan:
            raise StudyError("the trial plan is empty: the study has no stimuli to rate")
        if [p.index for p in plan] != list(range(len(plan))):
            raise StudyError("plan indices must be 0, 1, 2, ... in order")
        path.parent.mkdir(parents=True, exist_ok=True)
        created_at = created_at or utc_now()
        if session_id is None:
            session_id = _sha(_canonical([study_id, participant, seed, created_at]))[:16]
        header = {
            "session_id": session_id, "participant": participant, "study_id": study_id,
            "manifest_sha256": manifest_sha256, "seed": int(seed), "app_version": app_version,
            "created_at": created_at,
        }
        tmp = path.with_name(path.name + ".creating")
        tmp.unlink(missing_ok=True)
        con = _connect(tmp, readonly=False)
        try:
            con.execute("BEGIN IMMEDIATE")
            for stmt in _DDL.split(";"):
                if stmt.strip():
                    con.execute(stmt)
            con.execute("INSERT INTO meta VALUES ('schema', ?)", (SCHEMA_VERSION,))
            con.execute(
                "INSERT INTO session (session_id, participant, study_id, manifest_sha256, seed,"
                " app_version, created_at, settings, head_hash) VALUES (?,?,?,?,?,?,?,?,?)",
                (session_id, participant, study_id, manifest_sha256, int(seed), app_version,
                 created_at, _canonical(settings or {}), _genesis(header, plan)),
            )
            con.executemany(
                "INSERT INTO plan VALUES (?,?,?,?,?,NULL)",
                [(p.index, p.stimulus, p.reference, int(p.repetition),
                  int(p.is_hidden_reference)) for p in plan],
            )
            con.execute("COMMIT")
            con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            con.close()
        except BaseException:
            con.close()
            for suffix in ("", "-wal", "-shm"):
                Path(str(tmp) + suffix).unlink(missing_ok=True)
            raise
        # The file appears under its real name only once the plan is stored.
        for suffix in ("-wal", "-shm"):
            Path(str(tmp) + suffix).unlink(missing_ok=True)
        tmp.replace(path)
        return cls.open(path)

    @classmethod
    def open(cls, path: str | Path) -> SessionStore:
        """Open an existing session file for resuming (read-write)."""
        path = Path(path)
        con = _open_existing(path, readonly=False)
        return cls(con, path)

    def close(self) -> None:
        """Checkpoint the WAL into the main file and close."""
        with contextlib.suppress(sqlite3.Error):
            self._con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        self._con.close()

    def __enter__(self) -> SessionStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reading ----------------------------------------------------------------------
    @property
    def info(self) -> SessionInfo:
        return _info(_read_header(self._con))

    @property
    def is_finished(self) -> bool:
        return self.info.finished_at is not None

    def plan(self) -> list[PlannedTrial]:
        """The whole trial order, including trials re-queued at the end."""
        return _read_plan(self._con)

    def pending(self) -> list[PlannedTrial]:
        """Unanswered trials in plan order (trials superseded by a re-queue left out)."""
        return self._pending()

    def _pending(self) -> list[PlannedTrial]:
        rows = self._con.execute(
            "SELECT * FROM plan p WHERE NOT EXISTS (SELECT 1 FROM ratings r WHERE r.trial=p.idx)"
            " AND NOT EXISTS (SELECT 1 FROM plan q WHERE q.requeue_of=p.idx) ORDER BY idx"
        ).fetchall()
        return [PlannedTrial(r["idx"], r["stimulus"], r["reference"], r["repetition"],
                             bool(r["is_hidden_reference"]), r["requeue_of"]) for r in rows]

    def next_trial(self) -> PlannedTrial | None:
        """The first unanswered trial, or None when every trial is answered."""
        pending = self._pending()
        return pending[0] if pending else None

    def progress(self) -> tuple[int, int]:
        """(answered trials, trials to answer in total), re-queued trials counted once."""
        answered = self._con.execute("SELECT count(*) FROM ratings").fetchone()[0]
        return int(answered), int(answered) + len(self._pending())

    def ratings(self) -> list[dict[str, Any]]:
        """The tidy ratings rows of this session (see :data:`RATINGS_COLUMNS`)."""
        rows, problems = _ratings_from(self._con, self.path)
        if problems:
            raise StudyError("; ".join(str(p) for p in problems))
        return rows

    def presentations(self) -> list[dict[str, Any]]:
        """Presentation logs of every trial attempt, in order."""
        return [
            {"trial": r["trial"], "outcome": r["outcome"], "logged_at": r["logged_at"],
             **json.loads(r["details"])}
            for r in self._con.execute("SELECT * FROM presentations ORDER BY id")
        ]

    def events(self) -> list[dict[str, Any]]:
        return [
            {"at": r["at"], "kind": r["kind"], **json.loads(r["details"])}
            for r in self._con.execute("SELECT * FROM events ORDER BY id")
        ]

    # -- writing ----------------------------------------------------------------------
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

    def log_event(self, kind: str, **details: Any) -> None:
        """Append a session event (one committed transaction)."""
        self._con.execute("INSERT INTO events (at, kind, details) VALUES (?,?,?)",
                          (utc_now(), kind, _canonical(details)))

    def mark_started(self, *, display: dict[str, Any] | None = None) -> None:
        """Record that the participant began (or resumed) the session, with the display."""
        self._require_open()
        now = utc_now()
        with self._transaction():
            if display is not None:
                self._con.execute("UPDATE session SET display=?", (_canonical(display),))
            self._con.execute("UPDATE session SET started_at=COALESCE(started_at, ?)", (now,))
            self._con.execute("INSERT INTO events (at, kind, details) VALUES (?,?,?)",
                              (now, "start", _canonical(display or {})))

    def save_preflight(self, results: Iterable[dict[str, Any]], *, skipped: bool) -> None:
        """Store the pre-flight results (each a dict with at least name, ok, message)."""
        results = list(results)
        with self._transaction():
            self._con.execute(
                "UPDATE session SET preflight=?, preflight_skipped=?",
                (_canonical(results), int(skipped)),
            )
            self._con.execute("INSERT INTO events (at, kind, details) VALUES (?,?,?)",
                              (utc_now(), "preflight", _canonical(
                                  {"skipped": skipped,
                                   "failed": [r.get("name") for r in results if not r.get("ok")]})))

    def _transaction(self) -> _Tx:
        return _Tx(self._con)

    def record(self, trial_index: int, result: TrialResult) -> str:
        """Store the rating of the next unanswered trial; one committed transaction.

        Returns the row's hash. Raises :class:`StudyError` for a finished session, a trial out
        of order or an already answered one (no duplicates).
        """
        for name in ("rating", "rt_ms", "ms_on_reference", "ms_on_test",
                     "slider_first_move_ms", "max_flip_interval_ms"):
            _check_finite(name, getattr(result, name))
        with self._transaction():
            trial = self._check_next(trial_index)
            header = _read_header(self._con)
            row = _normalise_row({
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
                "switch_latencies_ms": _canonical([float(x) for x in
                                                   result.switch_latencies_ms]),
                "presented_at": result.presented_at,
                "answered_at": result.answered_at or utc_now(),
                "app_version": header["app_version"],
                "prev_hash": header["head_hash"],
            })
            row["row_hash"] = _row_hash(row)
            cols = (*_CHAINED, "row_hash")
            self._con.execute(
                f"INSERT INTO ratings ({','.join(cols)}) VALUES ({','.join('?' * len(cols))})",
                [row[c] for c in cols],
            )
            self._con.execute("UPDATE session SET n_ratings=?, head_hash=?",
                              (row["seq"], row["row_hash"]))
            self._log_presentation(trial.index, "rated", result)
        return row["row_hash"]

    def requeue(self, trial_index: int, result: TrialResult, reason: str) -> PlannedTrial:
        """Discard this attempt of the next trial (e.g. too many dropped frames) and append the
        same stimulus and repetition at the end of the plan; one committed transaction."""
        with self._transaction():
            trial = self._check_next(trial_index)
            new_idx = self._con.execute("SELECT max(idx) + 1 FROM plan").fetchone()[0]
            self._con.execute(
                "INSERT INTO plan VALUES (?,?,?,?,?,?)",
                (new_idx, trial.stimulus, trial.reference, trial.repetition,
                 int(trial.is_hidden_reference), trial.index),
            )
            self._log_presentation(trial.index, "requeued", result, reason=reason)
        return PlannedTrial(new_idx, trial.stimulus, trial.reference, trial.repetition,
                            trial.is_hidden_reference, trial.index)

    def _log_presentation(self, trial: int, outcome: str, result: TrialResult,
                          **extra: Any) -> None:
        details = {k: v for k, v in asdict(result).items() if k != "details"}
        details.update(result.details)
        details.update(extra)
        self._con.execute(
            "INSERT INTO presentations (trial, outcome, details, logged_at) VALUES (?,?,?,?)",
            (trial, outcome, _canonical(details), utc_now()),
        )

    def finish(self, *, allow_incomplete: bool = False) -> None:
        """Close the session for good: afterwards it refuses new ratings."""
        self._require_open()
        pending = len(self._pending())
        if pending and not allow_incomplete:
            raise StudyError(
                f"session {self.path} still has {pending} unanswered trial(s); it cannot be "
                "finished yet"
            )
        now = utc_now()
        with self._transaction():
            self._con.execute("UPDATE session SET finished_at=?", (now,))
            self._con.execute("INSERT INTO events (at, kind, details) VALUES (?,?,?)",
                              (now, "finish", _canonical({"unanswered": pending})))


class _Tx:
    """``BEGIN IMMEDIATE`` ... ``COMMIT`` (or ``ROLLBACK`` on error)."""

    def __init__(self, con: sqlite3.Connection) -> None:
        self._con = con

    def __enter__(self) -> None:
        self._con.execute("BEGIN IMMEDIATE")

    def __exit__(self, exc_type: object, *_: object) -> None:
        self._con.execute("COMMIT" if exc_type is None else "ROLLBACK")


# -- reading returned files -------------------------------------------------------------
def _ratings_from(
    con: sqlite3.Connection, path: Path, *, stop_at_break: bool = True
) -> tuple[list[dict[str, Any]], list[SessionProblem]]:
    problems: list[SessionProblem] = []
    try:
        header = _read_header(con)
        plan = _read_plan(con)
        raw = [dict(r) for r in con.execute("SELECT * FROM ratings ORDER BY seq")]
    except (sqlite3.DatabaseError, KeyError) as exc:
        return [], [SessionProblem(path, None, f"session tables unreadable ({exc})")]
    by_idx = {p.index: p for p in plan}
    original = [p for p in plan if p.requeue_of is None]
    try:
        prev = _genesis(header, original)
    except (KeyError, TypeError) as exc:
        return [], [SessionProblem(path, None, f"session record incomplete ({exc})")]
    rows: list[dict[str, Any]] = []
    for expected_seq, r in enumerate(raw, start=1):
        trial = r.get("trial")
        if r["prev_hash"] != prev:
            problems.append(SessionProblem(
                path, trial, "hash chain broken: this row does not follow the previous one "
                "(the session header, plan or an earlier row was edited or removed); rows from "
                "here on are not used"))
            break
        try:
            recomputed = _row_hash(_normalise_row(r))
        except (KeyError, TypeError, ValueError) as exc:
            problems.append(SessionProblem(path, trial, f"rating row unreadable ({exc})"))
            break
        if recomputed != r["row_hash"]:
            problems.append(SessionProblem(
                path, trial, "hash chain broken: the row's content does not match its hash "
                "(the row was edited); rows from here on are not used"))
            break
        if r["seq"] != expected_seq:
            problems.append(SessionProblem(path, trial, f"sequence number {r['seq']} where "
                                           f"{expected_seq} was expected"))
            break
        p = by_idx.get(trial)
        if p is None or (p.stimulus, p.repetition) != (r["stimulus"], r["repetition"]):
            problems.append(SessionProblem(
                path, trial, "rating row does not match the planned trial"))
            break
        prev = r["row_hash"]
        rows.append({
            "study": header["study_id"],
            "session": header["session_id"],
            "participant": header["participant"],
            "trial": int(r["trial"]),
            "stimulus": r["stimulus"],
            "reference": r["reference"],
            "repetition": int(r["repetition"]),
            "is_hidden_reference": bool(r["is_hidden_reference"]),
            "rating": float(r["rating"]),
            "rt_ms": float(r["rt_ms"]),
            "n_toggles": int(r["n_toggles"]),
            "ms_on_reference": float(r["ms_on_reference"]),
            "ms_on_test": float(r["ms_on_test"]),
            "dropped_frames": int(r["dropped_frames"]),
            "presented_at": r["presented_at"],
            "app_version": r["app_version"],
        })
    else:
        if header["head_hash"] != prev or int(header["n_ratings"]) != len(raw):
            problems.append(SessionProblem(
                path, None, f"the session record counts {header['n_ratings']} rating(s) "
                f"ending in a different hash than the {len(raw)} row(s) present: rating rows "
                "were removed or added outside the app"))
    return rows, problems


def read_ratings(path: str | Path) -> tuple[list[dict[str, Any]], list[SessionProblem]]:
    """Ratings rows of a session file (dicts with exactly :data:`RATINGS_COLUMNS`) and the
    problems found. Rows from a hash-chain break on are left out. Raises :class:`StudyError`
    only when the file is not a session file at all."""
    path = Path(path)
    con = _open_existing(path, readonly=True)
    try:
        return _ratings_from(con, path)
    finally:
        con.close()


def read_info(path: str | Path) -> SessionInfo:
    """The session record of a session file (read-only)."""
    path = Path(path)
    con = _open_existing(path, readonly=True)
    try:
        return _info(_read_header(con))
    except sqlite3.DatabaseError as exc:
        raise StudyError(f"{path}: session record unreadable ({exc})") from None
    finally:
        con.close()


@dataclass
class VerifyReport:
    """Result of :func:`verify_session`: ``intact`` (schema and hash chain fine) and
    ``complete`` (every planned trial answered and the session finished)."""

    path: Path
    intact: bool
    complete: bool
    n_ratings: int
    n_planned: int
    finished: bool
    problems: list[SessionProblem]
    info: SessionInfo | None = None

    @property
    def exit_code(self) -> int:
        """0 intact and complete, 1 intact but incomplete, 2 damaged."""
        if not self.intact:
            return 2
        return 0 if self.complete else 1


def verify_session(path: str | Path) -> VerifyReport:
    """Check a returned session file: schema, hash chain, plan consistency, completeness."""
    path = Path(path)
    con = _open_existing(path, readonly=True)
    try:
        rows, problems = _ratings_from(con, path)
        try:
            header = _read_header(con)
            info = _info(header)
            plan = _read_plan(con)
            integrity = con.execute("PRAGMA integrity_check").fetchone()[0]
        except (sqlite3.DatabaseError, json.JSONDecodeError) as exc:
            return VerifyReport(path, False, False, len(rows), 0, False,
                                [*problems, SessionProblem(path, None, f"unreadable: {exc}")])
    finally:
        con.close()
    if integrity != "ok":
        problems.append(SessionProblem(path, None, f"SQLite integrity check: {integrity}"))
    by_idx = {p.index: p for p in plan}
    for p in plan:
        if p.requeue_of is not None:
            orig = by_idx.get(p.requeue_of)
            if orig is None or (orig.stimulus, orig.repetition) != (p.stimulus, p.repetition):
                problems.append(SessionProblem(path, p.index, "re-queued trial does not match "
                                               "the trial it replaces"))
    seen = {(r["stimulus"], r["repetition"]) for r in rows}
    wanted = {(p.stimulus, p.repetition) for p in plan}
    answered = {r["trial"] for r in rows}
    superseded = {p.requeue_of for p in plan if p.requeue_of is not None}
    unanswered = [p.index for p in plan if p.index not in answered and p.index not in superseded]
    intact = not problems
    finished = info.finished_at is not None
    complete = intact and finished and not unanswered and seen == wanted
    return VerifyReport(path, intact, complete, len(rows), len(wanted), finished, problems, info)


def write_ratings_csv(rows: Iterable[dict[str, Any]], out: str | Path) -> Path:
    """Write ratings rows as the tidy CSV of DESIGN.md (columns in :data:`RATINGS_COLUMNS`)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=RATINGS_COLUMNS, extrasaction="raise")
        writer.writeheader()
        for row in rows:
            writer.writerow(row)
    return out
