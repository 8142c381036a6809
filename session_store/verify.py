"""Checking a returned session file: schema, hash chain, plan consistency, completeness, and
whether the main file holds everything (a ``-wal`` file beside it may hold ratings it lacks).
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

from .errors import StudyError
from .reader import SessionRecord, read_header, record_from
from .records import SessionInfo, SessionProblem
from .replica import tables_match_outbox
from .schema import open_existing, wal_pending_bytes


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
    warnings: list[str] = field(default_factory=list)

    @property
    def withdrawn(self) -> bool:
        return bool(self.info and self.info.withdrawn)

    @property
    def exit_code(self) -> int:
        """0 intact and complete, 1 intact but incomplete (or withdrawn), 2 damaged."""
        if not self.intact:
            return 2
        return 0 if self.complete else 1

    @property
    def state(self) -> str:
        """One word for listings: complete, incomplete, withdrawn or damaged."""
        if not self.intact:
            return "damaged"
        if self.complete:
            return "complete"
        return "withdrawn" if self.withdrawn else "incomplete"


def unmerged_wal_warning(path: Path, record: SessionRecord) -> str | None:
    """A warning when the ``-wal`` beside ``path`` holds committed data the main file lacks
    (the main file alone, read as immutable, has fewer ratings or another header)."""
    if wal_pending_bytes(path) == 0:
        return None
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?immutable=1", uri=True)
        con.row_factory = sqlite3.Row
        try:
            alone = read_header(con)
        finally:
            con.close()
    except sqlite3.DatabaseError:
        alone = None
    full = (record.info.finished_at, len(record.ratings))
    if alone is not None and (alone["finished_at"], int(alone["n_ratings"])) == full:
        return None
    missing = len(record.ratings) - (int(alone["n_ratings"]) if alone else 0)
    return (f"{path.name}-wal beside it holds {max(missing, 0)} committed rating(s) or the end "
            f"of the session that {path.name} alone lacks: send the zip made by 'cgvq-study "
            f"export {path.name}' (or keep the -wal file next to it)")


def verify_record(record: SessionRecord, integrity: str = "ok") -> VerifyReport:
    """Completeness and consistency of an already read session."""
    path = record.path
    problems = list(record.problems)
    if integrity != "ok":
        problems.append(SessionProblem(path, None, f"SQLite integrity check: {integrity}"))
    plan = record.plan
    by_idx = {p.index: p for p in plan}
    for p in plan:
        if p.requeue_of is not None:
            orig = by_idx.get(p.requeue_of)
            if orig is None or (orig.stimulus, orig.repetition) != (p.stimulus, p.repetition):
                problems.append(SessionProblem(path, p.index, "re-queued trial does not match "
                                               "the trial it replaces"))
    rows = record.ratings
    seen = {(r["stimulus"], r["repetition"]) for r in rows}
    wanted = {(p.stimulus, p.repetition) for p in plan}
    answered = {r["trial"] for r in rows}
    superseded = {p.requeue_of for p in plan if p.requeue_of is not None}
    unanswered = [p.index for p in plan if p.index not in answered and p.index not in superseded]
    intact = not problems
    finished = record.info.finished_at is not None
    complete = (intact and finished and not record.info.withdrawn and not unanswered
                and seen == wanted)
    return VerifyReport(path, intact, complete, len(rows), len(wanted), finished, problems,
                        record.info)


def verify_session(path: str | Path) -> VerifyReport:
    """Check a session file: schema, hash chain, plan consistency, completeness."""
    path = Path(path)
    con = open_existing(path, readonly=True)
    try:
        try:
            record = record_from(con, path)
        except StudyError as exc:
            return VerifyReport(path, False, False, 0, 0, False,
                                [SessionProblem(path, None, str(exc))])
        try:
            integrity = con.execute("PRAGMA integrity_check").fetchone()[0]
        except sqlite3.DatabaseError as exc:
            integrity = str(exc)
    finally:
        con.close()
    report = verify_record(record, integrity)
    for difference in tables_match_outbox(path):
        report.problems.append(SessionProblem(path, None, difference))
        report.intact = report.complete = False
    warning = unmerged_wal_warning(path, record)
    if warning:
        report.warnings.append(warning)
    return report

