"""Reading session files: everything in one read transaction, WAL included.

A session file may be read while the app is still writing it (the study server, a live
analysis). Header, plan, ratings, presentation logs and events are therefore read inside one
SQLite read transaction, so they come from one snapshot: reading them in separate statements
could see a rating row whose header update is not visible yet, and report a tampered file.
"""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .chain import follow_chain
from .errors import StudyError
from .records import PlannedTrial, SessionInfo, SessionProblem
from .schema import DAMAGE_ERRORS, has_table, open_existing

_INFO_JSON = {"settings": "{}", "display": "{}", "preflight": "[]"}


@dataclass
class SessionRecord:
    """One session file as read from one snapshot."""

    path: Path
    info: SessionInfo
    plan: list[PlannedTrial]
    ratings: list[dict[str, Any]]
    """Tidy rating rows (the ratings-table contract), up to the first hash-chain break."""
    presentations: list[dict[str, Any]]
    """Presentation logs of every trial attempt (``outcome`` rated or requeued), in order."""
    events: list[dict[str, Any]]
    problems: list[SessionProblem] = field(default_factory=list)
    answers: list[dict[str, Any]] = field(default_factory=list)
    """Every confirmed questionnaire answer in order (``value`` decoded); later rows of the
    same question replace earlier ones (see :func:`session_store.answers.latest_answers`)."""
    screenings: list[dict[str, Any]] = field(default_factory=list)
    """Vision-check results in order (``result`` decoded)."""

    @property
    def n_planned(self) -> int:
        """Distinct trials to answer (a re-queued trial counts once)."""
        return len({(p.stimulus, p.repetition) for p in self.plan})

    @property
    def n_requeued(self) -> int:
        return sum(1 for p in self.presentations if p.get("outcome") == "requeued")

    @property
    def intact(self) -> bool:
        return not self.problems


@dataclass
class _Snapshot:
    header: dict[str, Any]
    plan: list[PlannedTrial]
    ratings: list[dict[str, Any]]
    presentations: list[sqlite3.Row]
    events: list[sqlite3.Row]
    answers: list[sqlite3.Row]
    screenings: list[sqlite3.Row]


def _read_plan(con: sqlite3.Connection) -> list[PlannedTrial]:
    return [
        PlannedTrial(r["idx"], r["stimulus"], r["reference"], r["repetition"],
                     bool(r["is_hidden_reference"]), r["requeue_of"])
        for r in con.execute("SELECT * FROM plan ORDER BY idx")
    ]


def read_header(con: sqlite3.Connection) -> dict[str, Any]:
    row = con.execute("SELECT * FROM session").fetchone()
    if row is None:
        raise sqlite3.DatabaseError("session record missing")
    return dict(row)


def _snapshot(con: sqlite3.Connection) -> _Snapshot:
    con.execute("BEGIN")
    try:
        return _Snapshot(
            header=read_header(con),
            plan=_read_plan(con),
            ratings=[dict(r) for r in con.execute("SELECT * FROM ratings ORDER BY seq")],
            presentations=con.execute("SELECT * FROM presentations ORDER BY id").fetchall(),
            events=con.execute("SELECT * FROM events ORDER BY id").fetchall(),
            answers=_rows_if_present(con, "answers"),
            screenings=_rows_if_present(con, "screenings"),
        )
    finally:
        con.execute("COMMIT")


def _rows_if_present(con: sqlite3.Connection, table: str) -> list[sqlite3.Row]:
    if not has_table(con, table):
        return []
    return con.execute(f"SELECT * FROM {table} ORDER BY id").fetchall()


def _value(text: str) -> Any:
    try:
        return json.loads(text)
    except (ValueError, TypeError, RecursionError):
        return {"unreadable": True}


def _json(path: Path, name: str, text: str | None, default: str) -> Any:
    try:
        return json.loads(text or default)
    except (ValueError, TypeError, RecursionError):
        raise StudyError(f"{path}: the session record's {name} is not valid JSON (the file "
                         "was edited outside the app)") from None


def session_info(path: Path, header: dict[str, Any],
                 event_kinds: set[str] | None = None) -> SessionInfo:
    """The session record of a header row; a field edited into invalid JSON is a
    :class:`StudyError`."""
    parsed = {k: _json(path, k, header.get(k), d) for k, d in _INFO_JSON.items()}
    try:
        return SessionInfo(
            session_id=header["session_id"],
            participant=header["participant"],
            study_id=header["study_id"],
            manifest_sha256=header["manifest_sha256"],
            seed=int(header["seed"]),
            app_version=header["app_version"],
            created_at=header["created_at"],
            settings=parsed["settings"],
            display=parsed["display"],
            preflight=parsed["preflight"],
            preflight_skipped=bool(header["preflight_skipped"]),
            started_at=header["started_at"],
            finished_at=header["finished_at"],
            withdrawn="withdrawn" in (event_kinds or set()),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise StudyError(f"{path}: the session record is incomplete ({exc})") from None


def _details(path: Path, text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except (ValueError, TypeError, RecursionError):
        return {"unreadable": True}
    return value if isinstance(value, dict) else {"value": value}


def record_from(con: sqlite3.Connection, path: Path) -> SessionRecord:
    """Read a whole session from an open connection (one snapshot). Whatever a damaged file
    makes the read raise is a :class:`StudyError` naming the file, never a crash."""
    try:
        return _record_from(con, path)
    except DAMAGE_ERRORS as exc:
        raise StudyError(f"{path}: session tables unreadable ({_reason(exc)})") from None


def _reason(exc: BaseException) -> str:
    try:
        return str(exc) or type(exc).__name__
    except ValueError:
        return type(exc).__name__


def _record_from(con: sqlite3.Connection, path: Path) -> SessionRecord:
    try:
        snap = _snapshot(con)
    except DAMAGE_ERRORS as exc:
        raise StudyError(f"{path}: session tables unreadable ({_reason(exc)})") from None
    kinds = {str(e["kind"]) for e in snap.events}
    info = session_info(path, snap.header, kinds)
    try:
        firsts = [json.loads(e["details"] or "{}").get("first") for e in snap.events
                  if e["kind"] == "block"]
        rows, problems = follow_chain(path, snap.header, snap.plan, snap.ratings,
                                      first_block_end=min(firsts) if firsts else None)
    except DAMAGE_ERRORS as exc:
        rows, problems = [], [SessionProblem(path, None,
                                             f"session tables unreadable ({_reason(exc)})")]
    presentations = [{"trial": r["trial"], "outcome": r["outcome"], "logged_at": r["logged_at"],
                      **_details(path, r["details"])} for r in snap.presentations]
    events = [{"at": r["at"], "kind": r["kind"], **_details(path, r["details"])}
              for r in snap.events]
    answers = [{"questionnaire": r["questionnaire"], "question": r["question"],
                "value": _value(r["value"]), "page": r["page"], "ms": r["ms"],
                "answered_at": r["answered_at"]} for r in snap.answers]
    screenings = [{"test": r["test"], "outcome": r["outcome"], "result": _details(path,
                   r["result"]), "at": r["at"]} for r in snap.screenings]
    return SessionRecord(path, info, snap.plan, rows, presentations, events, problems,
                         answers, screenings)


def read_session(path: str | Path) -> SessionRecord:
    """Everything in a session file, from one consistent snapshot (read-only).

    Raises :class:`StudyError` only when the file is not a readable session file at all;
    a broken hash chain is reported in ``problems`` (rows from the break on are left out).
    """
    path = Path(path)
    con = open_existing(path, readonly=True)
    try:
        return record_from(con, path)
    finally:
        con.close()


def read_ratings(path: str | Path) -> tuple[list[dict[str, Any]], list[SessionProblem]]:
    """Ratings rows of a session file (the ratings-table contract) and the problems found.
    Rows from a hash-chain break on are left out. Raises :class:`StudyError` only when the
    file is not a readable session file at all."""
    record = read_session(path)
    return record.ratings, record.problems


def read_info(path: str | Path) -> SessionInfo:
    """The session record of a session file (read-only)."""
    return read_session(path).info
