"""Questionnaire answers and vision-check results as tables (the versioned ``cgvq-answers``
and ``cgvq-screenings`` contracts): one row per question a participant answered (the last
answer given), one per check. Separate from the ratings table on purpose: answers are
personal data, exported only when asked for."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from stimuli_manifests.tables import ANSWERS, SCREENINGS, write_table

from .reader import SessionRecord

#: The event the player logs when a failed vision check ends the session (``on_fail: end``);
#: the simulator writes it too, and the analysis counts such participants as not admitted.
ENDED_BY_VISION_CHECK = "ended_by_vision_check"


def latest_answers(answers: Iterable[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """(questionnaire, question) -> the last answer row given to it."""
    out: dict[tuple[str, str], dict[str, Any]] = {}
    for row in answers:
        out[(row["questionnaire"], row["question"])] = row
    return out


def answer_rows(record: SessionRecord) -> list[dict[str, Any]]:
    """The answers table rows of one session (last answer per question, in answer order)."""
    info = record.info
    return [{"study": info.study_id, "session": info.session_id,
             "participant": info.participant, "questionnaire": q, "question": question,
             "value": json.dumps(row["value"], ensure_ascii=False), "page": row["page"],
             "ms": row["ms"], "answered_at": row["answered_at"]}
            for (q, question), row in latest_answers(record.answers).items()]


def screening_rows(record: SessionRecord) -> list[dict[str, Any]]:
    """The screenings table rows of one session."""
    info = record.info
    return [{"study": info.study_id, "session": info.session_id,
             "participant": info.participant, "test": s["test"], "outcome": s["outcome"],
             "at": s["at"], "result": json.dumps(s["result"], ensure_ascii=False,
                                                 sort_keys=True)}
            for s in record.screenings]


def write_answers_csv(rows: Iterable[dict[str, Any]], out: str | Path) -> Path:
    return write_table(out, ANSWERS, rows)


def write_screenings_csv(rows: Iterable[dict[str, Any]], out: str | Path) -> Path:
    return write_table(out, SCREENINGS, rows)
