"""Session files in tests: bare ones made in a line, and whole files read for comparisons."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from session_store import PlannedTrial, SessionStore, TrialResult
from session_store.outbox import OutboxEntry, read_entries
from session_store.replica import _dump
from session_store.schema import open_existing


@contextmanager
def _read_only(path: Path) -> Iterator[sqlite3.Connection]:
    con = open_existing(path, readonly=True)
    try:
        yield con
    finally:
        con.close()


def session_tables(path: Path) -> dict[str, list[tuple]]:
    """Every table of a session file as rows (what two copies of a session must share)."""
    with _read_only(path) as con:
        return _dump(con)


def session_entries(path: Path) -> list[OutboxEntry]:
    """The change log (outbox) of a session file, entry by entry, as the uploader sends it."""
    with _read_only(path) as con:
        return read_entries(con)


def bare_plan(n: int) -> list[PlannedTrial]:
    """``n`` trials over three stimuli of one reference, no hidden references."""
    return [PlannedTrial(i, f"S{i % 3}", "R", i // 3 + 1, False) for i in range(n)]


def plain_result(rating: float) -> TrialResult:
    """A trial result in which only the rating matters."""
    return TrialResult(rating=rating, rt_ms=1000.0, n_toggles=1, ms_on_reference=1.0,
                       ms_on_test=2.0, presented_at="2026-01-01T00:00:00.000Z")


def bare_session(path: Path, participant: str = "P01", n: int = 6) -> SessionStore:
    """A new session file of study "s" (no manifest) with ``n`` planned trials, open."""
    return SessionStore.create(path, participant=participant, study_id="s", manifest_sha256=None,
                               seed=1, app_version="t", plan=bare_plan(n))
