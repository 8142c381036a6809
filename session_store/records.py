"""The plain records of a session: planned trials, trial results, the session header, problems."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any


def utc_now() -> str:
    """The current time as ISO 8601 UTC with milliseconds (``2026-01-01T12:00:00.123Z``)."""
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


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
    """Something wrong with a session file; ``row`` is the trial index when one is concerned.
    ``nothing_to_check``: the path given is missing or a folder without session files, so no
    file was looked at (not a damaged file)."""

    path: Path
    row: int | None
    message: str
    nothing_to_check: bool = False

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
    withdrawn: bool = False
    """The participant withdrew (from the pause screen); the session is closed, not complete."""
