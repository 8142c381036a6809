"""What a participant's run is given (the options of ``cgvq-study run``, checked before
anything is created) and how it ended: the app's inputs and outputs, apart from the order of
screens in :mod:`.app`."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from session_store.errors import StudyError

from .display import MIN_WINDOW

MAX_SEED = 2**63 - 1  # the session file stores the seed as a signed 64-bit integer


@dataclass
class RunOptions:
    """Options of ``cgvq-study run``."""

    participant: str
    windowed: bool = False
    skip_preflight: bool = False
    seed: int | None = None
    sessions_dir: Path | None = None
    practice: int = 2
    refresh_hz: float | None = None
    max_dropped_frames: int = 10
    break_every: int = 40
    window_size: tuple[int, int] | None = None
    screenshots: Path | None = None
    force_pacer: bool = False
    pilot_no_vsync: bool = False
    upload_report: Callable[[], tuple[bool, str]] | None = None
    """With a study server: waits for the last uploads and says (everything arrived, the
    sentence for the end screen); the end screen then shows it."""
    on_commit: Callable[[], None] | None = None
    """With a study server: a rating was committed (the uploader tries at once, also while it
    backs off after an outage); must not block."""
    ended_by_server: Callable[[], str | None] | None = None
    """With a study server: why it no longer accepts this session (the participant was
    withdrawn), else None; asked before each trial, and the session then ends there."""
    files_from_server: bool = False
    """The study was downloaded from a study server: a damaged file is fetched again when
    the participant starts again, which is what a failed file check then advises."""
    files_verified: Mapping[Path, str] = field(default_factory=dict)
    """Study files the download hashed in this run (resolved path to sha256): the file
    check compares them instead of reading them a second time."""
    next_block: Callable[[str, int, str | None], dict[str, Any]] | None = None
    """With a study server, in an adaptive study: asks for block ``k`` of session ``id``
    (after the last stimulus shown); the server's answer. Without one the app plans uniform
    blocks itself."""

    @property
    def pilot_allowed(self) -> bool:
        """Flips may be paced without vsync (an experimenter's pilot or test run)."""
        return self.pilot_no_vsync or self.force_pacer or self.skip_preflight

    def validate(self) -> None:
        """Refuse invalid options before anything is created (one-line errors)."""
        if self.window_size is not None:
            w, h = self.window_size
            if w < MIN_WINDOW[0] or h < MIN_WINDOW[1]:
                raise StudyError(f"--window-size {w}x{h} is too small: the study's screens "
                                 f"need at least {MIN_WINDOW[0]}x{MIN_WINDOW[1]}")
            if w > 16384 or h > 16384:
                raise StudyError(f"--window-size {w}x{h} is larger than any screen")
        if self.refresh_hz is not None:
            if not math.isfinite(self.refresh_hz) or not 20 <= self.refresh_hz <= 500:
                raise StudyError(f"--refresh-hz must be between 20 and 500, got "
                                 f"{self.refresh_hz:g}")
            if not (self.pilot_no_vsync or self.force_pacer):
                raise StudyError("--refresh-hz sets the pacing rate of the pilot mode without "
                                 "vsync; add --pilot-no-vsync (with vsync the refresh rate is "
                                 "measured)")
        if self.seed is not None and not 0 <= self.seed <= MAX_SEED:
            raise StudyError(f"--seed must be a whole number from 0 to {MAX_SEED}, got "
                             f"{self.seed}; leave it out to derive the seed from the study and "
                             "participant")
        if self.practice < 0:
            raise StudyError(f"--practice must be 0 or more, got {self.practice}")
        if self.break_every < 0:
            raise StudyError(f"--break-every must be 0 (never) or more, got {self.break_every}")
        if self.max_dropped_frames < -1:
            raise StudyError("--max-dropped-frames must be -1 (never re-queue) or more, got "
                             f"{self.max_dropped_frames}")


@dataclass
class RunOutcome:
    """How a run ended: ``finished``, ``quit`` (resumable), ``withdrawn``, ``ended`` (the study
    server no longer accepts the session), ``screened-out``
    (a failed vision check with ``on_fail: end``; ``screened_by`` says which), ``declined``
    (no consent) or ``closed`` (the window closed before the session started or, on a
    return, before it reopened: then ``session_path`` is the untouched session)."""

    status: str
    session_path: Path | None
    answered: int = 0
    total: int = 0
    screened_by: str = ""
