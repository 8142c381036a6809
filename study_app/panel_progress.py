"""Where a participant stands in the manifest's panel: which vision checks and which
questionnaires are still to do, and on which page a questionnaire resumes after a crash.

Everything is read back from the session file (answers, vision-check results and the
``questionnaire`` events the app logs when one is done or skipped), so a run killed in the
middle of a questionnaire resumes at the page it was on with every confirmed answer kept.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from session_store.answers import latest_answers
from stimuli_manifests.panel import Panel, Questionnaire

QUESTIONNAIRE_EVENT = "questionnaire"
"""Event kind logged when a questionnaire is finished (``outcome`` done) or skipped."""


@dataclass
class QuestionnaireProgress:
    """One questionnaire: the answers given so far and the page to show next."""

    questionnaire: Questionnaire
    answered: dict[str, Any] = field(default_factory=dict)
    start_page: int = 0


@dataclass
class PanelProgress:
    """What remains of the panel for one session."""

    vision_todo: list[str]
    vision_results: dict[str, str]
    before: list[QuestionnaireProgress]
    after: list[QuestionnaireProgress]

    @property
    def failed_vision(self) -> list[str]:
        return sorted(t for t, outcome in self.vision_results.items() if outcome == "failed")


def vision_tests(panel: Panel | None) -> list[str]:
    """The vision checks the panel asks for, in the order they are shown."""
    vs = panel.vision_screening if panel is not None else None
    if vs is None:
        return []
    return [name for name, on in (("colour", vs.colour), ("acuity", vs.acuity)) if on]


def panel_progress(panel: Panel | None, answers: list[dict[str, Any]],
                   screenings: list[dict[str, Any]], events: list[dict[str, Any]]
                   ) -> PanelProgress:
    """The remaining panel of a session from its answers, vision results and events."""
    results = {s["test"]: s["outcome"] for s in screenings}
    closed = {e.get("questionnaire") for e in events if e.get("kind") == QUESTIONNAIRE_EVENT}
    latest = latest_answers(answers)
    remaining: dict[str, list[QuestionnaireProgress]] = {"before": [], "after": []}
    for qn in (panel.questionnaires if panel is not None else []):
        if qn.id in closed:
            continue
        given = {q: row["value"] for (qid, q), row in latest.items() if qid == qn.id}
        pages = [row["page"] for (qid, _), row in latest.items() if qid == qn.id]
        remaining[qn.when].append(QuestionnaireProgress(
            qn, given, min(max(pages, default=0), len(qn.pages) - 1)))
    return PanelProgress([t for t in vision_tests(panel) if t not in results], results,
                         remaining["before"], remaining["after"])
