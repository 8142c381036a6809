"""Whether the player may continue an existing session file: checked before any window opens.

A session is continued only when it is this participant's session of this study, still
open, and intact: its rating chain unbroken and its tables what its change log says. New
ratings are chained to the file's last one, so continuing a damaged file would put every
later rating behind the break, where no reader uses it; continuing someone else's file would
record this person's ratings under the other's id. Each refusal is one line that says what
to do.
"""

from __future__ import annotations

from pathlib import Path

from session_store import SessionInfo, read_session, tables_match_outbox
from session_store.errors import StudyError


def check_resumable(path: Path, *, participant: str, study_id: str,
                    manifest_sha256: str | None, seed: int | None) -> None:
    """Refuse (:class:`StudyError`, one line) to continue the session file ``path`` for
    ``participant`` of study ``study_id`` (its manifest's sha256; ``seed`` the ``--seed``
    given, or None); return when it may be continued."""
    try:
        record = read_session(path)
    except StudyError as exc:
        raise StudyError(damaged_message(path, str(exc), readable=False)) from None
    info = record.info
    _check_owner(path, info, participant, study_id)
    _check_open(path, info, participant)
    problems = [p.message for p in record.problems] or tables_match_outbox(path)
    if problems:
        raise StudyError(damaged_message(path, problems[0]))
    if info.manifest_sha256 and info.manifest_sha256 != manifest_sha256:
        raise StudyError(
            f"the study's manifest changed since this session started ({path}); resume with "
            "the original study folder")
    if seed is not None and seed != info.seed:
        raise StudyError(
            f"--seed {seed}: this session was started with seed {info.seed} (kept in "
            f"{path.name}); a resumed session keeps its plan: leave --seed out")


def _check_owner(path: Path, info: SessionInfo, participant: str, study_id: str) -> None:
    """The file must hold this participant's session of this study (a copied, renamed or
    swapped file would otherwise take this person's ratings under another id)."""
    if info.participant != participant:
        raise StudyError(
            f"{path.name} holds the session of participant {info.participant}, not "
            f"{participant}; it is not continued. Check --participant (and --sessions-dir); "
            "if the file was copied or renamed, ask the experimenter")
    if info.study_id != study_id:
        raise StudyError(
            f"{path.name} holds a session of study {info.study_id}, not of this study "
            f"({study_id}); it is not continued. Check the study folder and --sessions-dir")


def _check_open(path: Path, info: SessionInfo, participant: str) -> None:
    """A withdrawn or finished session takes nothing more."""
    if info.withdrawn:
        raise StudyError(
            f"participant {participant} withdrew from this study ({path}); nothing left to "
            "do: send that file to the experimenter")
    if info.finished_at is not None:
        raise StudyError(
            f"the session of participant {participant} is already finished ({path}); "
            "nothing left to do: send that file to the experimenter")


def damaged_message(path: Path, problem: str, *, readable: bool = True) -> str:
    """The refusal for a damaged session file: keep it as it is and send it (exported where
    it can still be read; ``export`` refuses a file SQLite cannot open, so then the file
    itself, with the files SQLite keeps beside it)."""
    if readable:
        send = (f"export it as it is ('cgvq-study export {path}') and send the zip to the "
                "experimenter")
    else:
        send = (f"send the file {path} as it is to the experimenter, with any file beside it "
                f"whose name starts with {path.name}")
    return (f"your session file {path.name} is damaged ({problem}), so it is not continued: "
            f"do not run the study again with it; {send}, who will tell you whether to start "
            "a fresh session")
