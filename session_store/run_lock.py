"""One run per participant: the session file's lock (:mod:`stimuli_manifests.file_lock`),
refused with the session package's error and a participant's wording."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from stimuli_manifests.file_lock import FileLock, lock_path_for, read_holder

from .errors import StudyError

__all__ = ["RunLock", "lock_path_for", "read_holder"]


class RunLock(FileLock):
    """The lock of one participant's session file (or, with ``busy``, of another file a
    study keeps to one process: the server's database)."""

    error = StudyError

    def __init__(self, path: Path, owner: str, *,
                 busy: Callable[[str], str] | None = None) -> None:
        super().__init__(path, owner, busy=busy or (
            lambda holder: f"participant {owner} already has a run open{holder}; finish or "
                           "close that window first (only one run per participant at a time)"))
