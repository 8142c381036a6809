"""Participant ids: what may name a session file, an export and an upload."""

from __future__ import annotations

import re

from .errors import StudyError

MAX_PARTICIPANT_ID = 64
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


def check_participant_id(participant: object) -> str:
    """Return ``participant`` when it is a valid id, else raise :class:`StudyError`.

    Ids become file names on every platform: 1 to 64 characters, letters, digits, '.', '-'
    and '_', starting with a letter or digit (so no hidden files, no '..', no path).
    """
    text = participant if isinstance(participant, str) else repr(participant)
    if not isinstance(participant, str) or not _ID.fullmatch(participant):
        shown = text if len(text) <= 40 else text[:37] + "..."
        raise StudyError(
            f"participant id {shown!r} is not valid: use 1 to {MAX_PARTICIPANT_ID} letters, "
            "digits, '.', '-' or '_', starting with a letter or digit (e.g. P01)")
    if len(participant) > MAX_PARTICIPANT_ID:
        raise StudyError(
            f"participant id {participant[:20]!r}... is {len(participant)} characters long; "
            f"use at most {MAX_PARTICIPANT_ID} (e.g. P01)")
    return participant
