"""The panel as a paper describes it: who took part, what they answered, how they were screened.

From the questionnaire answers and vision-check results in the session files (see
``session_store.answers``) and the manifest's panel block (``stimuli_manifests.panel``) this
module builds the paper's sentence ("20 participants aged 25-57, 18 male and 2 female, with
normal or corrected-to-normal vision; 13 of 20 answered the post-study survey"), the counts
of every answer, the Likert distributions and the screening outcome of every participant.
Free-text answers are kept apart from participant ids and in a fixed order, so the report
cannot link a comment to a rater.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from stimuli_manifests.panel import (
    PREFER_NOT_TO_SAY,
    Likert,
    Number,
    Panel,
    PanelError,
    Text,
)

from .data import Exclusion, InputProblem, PanelAnswers, RatingSet, drop_unrated, rater_order
from .errors import AnalysisError
from .sessions import Session

log = logging.getLogger(__name__)

NOT_ANSWERED = "(no answer)"
PREFERRED_NOT = "Prefer not to say"
# Question ids of the demographics template that the paper's sentence is made from.
AGE, GENDER, VISION = "age", "gender", "vision"
BACKGROUND = "graphics_background"
CORRECTED_VALUES = ("normal", "corrected")


# A check taken in several sessions counts by its worst outcome: passing it later does not undo
# a failure (the ratings kept of a merged participant may be the ones made after it).
OUTCOME_RANK = {"passed": 0, "inconclusive": 1, "failed": 2}
# How the paper's sentence names the template's gender options after a count ("12 male").
GENDER_WORDS = {"Male": "male", "Female": "female", "Non-binary": "non-binary",
                "Another gender": "of another gender"}
_REFUSED = object()


@dataclass
class SessionPanel(PanelAnswers):
    """:class:`PanelAnswers` read from session files, with the stored answers that the
    question's rule refused (left out; the report lists them with the input problems)."""

    problems: list[InputProblem] = field(default_factory=list)


def panel_from_sessions(sessions: list[Session], definition: Panel | None) -> SessionPanel:
    """Merge the answers of each participant's sessions (the later valid answer wins) and
    their vision checks (the worst outcome of each check wins). An answer taken back ("no
    answer" stored) erases the answers of its own session only: a later session shows the
    questionnaire afresh, so taking back what was typed there says nothing about what an
    earlier session holds."""
    out = SessionPanel(definition=definition)
    for session in sorted(sessions, key=lambda s: s.order_key):
        who = session.info.participant
        latest: dict[str, Any] = {}
        for row in session.answers:
            value = _checked_answer(definition, session.path, row, out.problems)
            if value is not _REFUSED:
                latest[row["question"]] = value
        merged = out.answers.setdefault(who, {})
        for question, value in latest.items():
            if value is not None or question not in merged:
                merged[question] = value
        for row in session.screenings:
            tests = out.screenings.setdefault(who, {})
            tests[row["test"]] = worse_outcome(tests.get(row["test"]), row["outcome"])
    return out


def worse_outcome(before: str | None, now: str) -> str:
    """The outcome a check keeps when it was taken again: failed > inconclusive > passed."""
    if before is None or OUTCOME_RANK.get(now, 1) > OUTCOME_RANK.get(before, 1):
        return now
    return before


def _checked_answer(definition: Panel | None, path: str, row: dict[str, Any],
                    problems: list[InputProblem]) -> Any:
    """The stored answer as the question's rule normalises it, or ``_REFUSED`` (with an input
    problem) when the rule refuses it: a session written by another tool or an older app may
    hold answers the player would never have stored."""
    if definition is None or row["value"] is None:  # None: no answer, or one taken back
        return row["value"]
    try:
        return definition.check(str(row["questionnaire"]), str(row["question"]), row["value"])
    except PanelError as exc:
        question = str(row["question"])[:40]
        reason = str(exc).removeprefix(f"{question}: ")
        problem = InputProblem(path, None, f"answer {question}: {reason}; the answer is left out")
        log.warning("input problem: %s", problem)
        problems.append(problem)
        return _REFUSED


def panel_problems(data: PanelAnswers | None) -> list[InputProblem]:
    """The answers left out when the sessions were read (see :class:`SessionPanel`)."""
    return list(getattr(data, "problems", []) or [])


def likert_keys(points: Sequence[str]) -> list[str]:
    """The name each Likert point is counted under: its label, or "k (label)" where a label
    is repeated (a scale labelled only at its ends and middle), so that no two points share
    one count."""
    seen = Counter(points)
    return [p if seen[p] == 1 else f"{k} ({p})" for k, p in enumerate(points, 1)]


@dataclass
class QuestionSummary:
    """Counts of one question's answers among the panel (labels in the question's order)."""

    id: str
    questionnaire: str
    text: str
    kind: str
    counts: dict[str, int]
    n_answered: int
    values: list[float] = field(default_factory=list)  # numbers (age) as given


@dataclass
class PanelSummary:
    """Everything the report and summary.json say about the panel."""

    n_participants: int
    sentence: str
    questions: list[QuestionSummary]
    answered: dict[str, int]  # questionnaire id -> participants who answered any question
    free_text: dict[str, list[str]]  # question id -> answers (sorted, no participant ids)
    screening: list[dict[str, Any]]  # one row per participant with a vision check
    failed_vision: list[str]

    def likert(self) -> list[QuestionSummary]:
        return [q for q in self.questions if q.kind == "likert"]


def _label(question: Any, value: Any) -> str:
    if value is None:
        return NOT_ANSWERED
    if value == PREFER_NOT_TO_SAY:
        return PREFERRED_NOT
    if isinstance(question, Likert):
        keys = likert_keys(question.points)
        whole = isinstance(value, int) and not isinstance(value, bool)
        return keys[value - 1] if whole and 1 <= value <= len(keys) else str(value)
    options = {o.value: o.label for o in getattr(question, "options", [])}
    if isinstance(value, list):
        return ", ".join(options.get(v, str(v)) for v in value)
    return options.get(value, str(value))


def _counts(question: Any, values: list[Any]) -> dict[str, int]:
    if isinstance(question, Likert):
        order = likert_keys(question.points)
    else:
        order = [o.label for o in getattr(question, "options", [])]
    seen = Counter()
    for value in values:
        if isinstance(value, list):  # multiple choice: each chosen option counts
            seen.update(_label(question, [v]) for v in value)
        else:
            seen[_label(question, value)] += 1
    extra = [k for k in seen if k not in order and k not in (PREFERRED_NOT, NOT_ANSWERED)]
    keys = order + sorted(extra) + [PREFERRED_NOT, NOT_ANSWERED]
    return {k: int(seen.get(k, 0)) for k in keys if k in order or seen.get(k)}


def summarise_panel(panel: Panel, data: PanelAnswers, participants: list[str],
                    everyone: list[str] | None = None) -> PanelSummary:
    """The panel of ``participants`` (the raters whose ratings were used); the screening
    table, the failed list and the sentence's screening clause cover ``everyone`` (all
    raters read, also those left out, and participants a vision check stopped before they
    rated)."""
    everyone = list(everyone or participants)
    n = len(participants)
    questions, free_text, answered = [], {}, {}
    for qn in panel.questionnaires:
        answered[qn.id] = sum(
            any(data.answers.get(p, {}).get(q.id) is not None for q in qn.questions())
            for p in participants)
        for q in qn.questions():
            given = [data.answers.get(p, {}).get(q.id) for p in participants]
            if isinstance(q, Text):
                free_text[q.id] = sorted(str(v) for v in given
                                         if isinstance(v, str) and v != PREFER_NOT_TO_SAY)
                continue
            numbers = [float(v) for v in given if isinstance(v, int | float)
                       and not isinstance(v, bool)] if isinstance(q, Number) else []
            counts = {} if isinstance(q, Number) else _counts(q, given)
            if isinstance(q, Number):
                counts = {PREFERRED_NOT: sum(v == PREFER_NOT_TO_SAY for v in given),
                          NOT_ANSWERED: sum(v is None for v in given)}
            questions.append(QuestionSummary(
                q.id, qn.id, q.text, q.type, counts,
                sum(v is not None for v in given), numbers))
    screening = [{"participant": p, **{test: outcome for test, outcome in
                                       sorted(data.screenings.get(p, {}).items())},
                  "ratings used": "yes" if p in participants else "no"}
                 for p in everyone if p in data.screenings]
    failed = [p for p in data.failed_vision() if p in everyone]
    return PanelSummary(n, panel_sentence(panel, data, participants, everyone), questions,
                        answered, free_text, screening, failed)


def panel_sentence(panel: Panel, data: PanelAnswers, participants: list[str],
                   everyone: list[str] | None = None) -> str:
    """The sentence a paper writes about its panel, from what the participants answered;
    participants in ``everyone`` but not in ``participants`` who failed a vision check are
    counted in a clause of their own (excluded, or not admitted by ``on_fail: end``)."""
    n = len(participants)
    parts = [f"{n} participant{'s' if n != 1 else ''}"]
    answers = [data.answers.get(p, {}) for p in participants]
    ids = {q.id for qn in panel.questionnaires for q in qn.questions()}
    if AGE in ids:
        ages = [a[AGE] for a in answers if isinstance(a.get(AGE), int | float)
                and not isinstance(a.get(AGE), bool)]
        if ages:
            lo, hi = min(ages), max(ages)
            parts[0] += f" aged {lo:g}" if lo == hi else f" aged {lo:g}-{hi:g}"
            notes = ([f"mean {np.mean(ages):.1f}, SD {np.std(ages, ddof=1):.1f}"]
                     if len(ages) >= 2 and lo != hi else [])
            if len(ages) < n:
                notes.append(f"{n - len(ages)} did not give their age")
            if notes:
                parts[0] += f" ({'; '.join(notes)})"
    if GENDER in ids:
        gender = _gender_part(panel.question(GENDER), answers)
        if gender.startswith("("):
            parts[-1] += " " + gender
        elif gender:
            parts.append(gender)
    if VISION in ids:
        good = sum(a.get(VISION) in CORRECTED_VALUES for a in answers)
        silent = sum(a.get(VISION) is None for a in answers)
        said = n - silent
        unsaid = f"; {silent} did not say how they see" if silent else ""
        if said and good == said:
            parts.append(f"with normal or corrected-to-normal vision (self-reported{unsaid})")
        elif said:
            parts.append(f"{good} of {said} with normal or corrected-to-normal vision "
                         f"(self-reported{unsaid})")
        elif silent:
            parts.append(f"{silent} did not say how they see")
    if BACKGROUND in ids:
        said = [a.get(BACKGROUND) for a in answers if a.get(BACKGROUND) in ("yes", "no")]
        if said:
            experts = sum(v == "yes" for v in said)
            parts.append(f"{experts} of {len(said)} working or studying in computer "
                         "graphics, vision or video")
    sentence = ", ".join(parts)
    after = panel.questionnaires_at("after")
    clauses = []
    for qn in after:
        k = sum(any(data.answers.get(p, {}).get(q.id) is not None for q in qn.questions())
                for p in participants)
        name = ("the post-study survey" if len(after) == 1 else
                f"the post-study questionnaire {qn.title!r}")
        clauses.append(f"{k} of {n} answered {name}")
    clauses += _screening_clauses(panel, data, participants, everyone or [])
    return sentence + ("; " + "; ".join(clauses) if clauses else "") + "."


def _gender_part(question: Any, answers: list[dict[str, Any]]) -> str:
    """"12 male and 8 female" for the template's labels; labels the sentence cannot put
    after a number ("Man", "Woman") are listed as they are: "(gender: Man 12, Woman 8)"."""
    counts = Counter(_label(question, a.get(GENDER)) for a in answers)
    named = [(label, c) for label, c in counts.most_common()
             if label not in (PREFERRED_NOT, NOT_ANSWERED)]
    unsaid = counts.get(PREFERRED_NOT, 0) + counts.get(NOT_ANSWERED, 0)
    said = [f"{unsaid} did not say"] if unsaid else []
    if all(label in GENDER_WORDS for label, _ in named):
        listed = [f"{c} {GENDER_WORDS[label]}" for label, c in named] + said
        return _join(listed) if listed else ""
    return "(gender: " + ", ".join(f"{label} {c}" for label, c in named) + (
        f"; {said[0]}" if said else "") + ")"


def _screening_clauses(panel: Panel, data: PanelAnswers, participants: list[str],
                       everyone: list[str]) -> list[str]:
    """How many of the panel took and failed the vision screening, and how many further
    participants failed it and are therefore not in the panel."""
    clauses = []
    screened = [p for p in participants if p in data.screenings]
    if screened:
        clauses.append(_screened_clause(data, screened).replace(
            "the remote vision screening", f"the remote vision screening{_tests(panel)}", 1))
    others = rater_order(p for p in everyone if p not in participants and _failed(data, p))
    if others:
        k = len(others)
        ended = panel.vision_screening is not None and panel.vision_screening.on_fail == "end"
        were = "were" if k != 1 else "was"
        how = f"{were} not admitted (the check ended their session)" if ended else \
            f"{were} left out of the analysis"
        clauses.append(f"{k} further participant{'s' if k != 1 else ''} failed it and {how}")
    return clauses


OPTOTYPES = {"landolt_c": "Landolt C", "tumbling_e": "tumbling E"}


def _tests(panel: Panel) -> str:
    """" (colour: generated pseudo-isochromatic plates; acuity: Landolt C, passed at logMAR
    0.3 and Weber contrast 0.063; at 60 cm on uncalibrated screens, not a diagnosis)"."""
    vs = panel.vision_screening
    if vs is None:
        return ""
    tests = (["colour: generated pseudo-isochromatic plates"] if vs.colour else []) + (
        [f"acuity: {OPTOTYPES.get(vs.optotype, vs.optotype)}, passed at logMAR "
         f"{vs.acuity_logmar:g} and Weber contrast {vs.contrast_weber:g}"] if vs.acuity else [])
    if not tests:
        return ""
    return (f" ({'; '.join(tests)}; at {vs.viewing_distance_cm:g} cm on the participants' "
            "own uncalibrated screens, a screening, not a diagnosis)")


def _screened_clause(data: PanelAnswers, screened: list[str]) -> str:
    """"16 took the remote vision screening: 13 passed, 2 failed it (colour 1, acuity 1) and
    1 was inconclusive; the ratings of the 2 who failed were kept (flagged, not excluded)"."""
    failed = [p for p in screened if _failed(data, p)]
    unsure = [p for p in screened if p not in failed
              and "inconclusive" in data.screenings.get(p, {}).values()]
    passed = len(screened) - len(failed) - len(unsure)
    if not failed and not unsure:
        return f"{len(screened)} took the remote vision screening and all passed it"
    tests = Counter(t for p in failed for t, o in data.screenings.get(p, {}).items()
                    if o == "failed")
    outcomes = [f"{passed} passed"]
    if failed:
        outcomes.append(f"{len(failed)} failed it (" + ", ".join(
            f"{t} {c}" for t, c in sorted(tests.items())) + ")")
    if unsure:
        outcomes.append(f"{len(unsure)} {'was' if len(unsure) == 1 else 'were'} inconclusive")
    text = f"{len(screened)} took the remote vision screening: {_join(outcomes)}"
    if failed:
        who = "the one who failed" if len(failed) == 1 else f"the {len(failed)} who failed"
        text += f"; the ratings of {who} were kept (flagged, not excluded)"
    return text


def _failed(data: PanelAnswers, participant: str) -> bool:
    return "failed" in data.screenings.get(participant, {}).values()


def _join(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def drop_failed_vision(rs: RatingSet) -> RatingSet:
    """Leave out raters who failed a vision check (``--exclude-failed-vision``), each as an
    :class:`~analysis.data.Exclusion` like any other."""
    failed = set(rs.panel.failed_vision()) if rs.panel is not None else set()
    drop = [k for k, r in enumerate(rs.raters) if r in failed]
    if not drop:
        return rs
    keep = [k for k in range(rs.n_raters) if k not in drop]
    if len(keep) < 2:
        raise AnalysisError(f"only {len(keep)} rater(s) passed the vision screening; analyse "
                            "without --exclude-failed-vision")
    info = rs.rater_info.copy() if rs.rater_info is not None else None
    exclusions = list(rs.exclusions)
    for k in drop:
        rater = rs.raters[k]
        tests = sorted(t for t, o in rs.panel.screenings[rater].items() if o == "failed")
        if info is not None and rater in info.index:
            info.loc[rater, "status"] = "excluded (vision check)"
        exclusions.append(Exclusion(
            "failed vision check", rater,
            f"failed the remote {' and '.join(tests)} check (a screening, not a diagnosis)",
            "--exclude-failed-vision"))
    out = replace(rs.with_raters(keep), exclusions=exclusions, rater_info=info)
    return drop_unrated(out, "vision check",
                        "their raters failed a vision check; --exclude-failed-vision")


def vision_column(rs: RatingSet, raters: list[str]) -> list[str]:
    """Per rater, the vision checks and their outcomes ("colour failed, acuity passed")."""
    screenings = rs.panel.screenings if rs.panel is not None else {}
    return [", ".join(f"{t} {o}" for t, o in sorted(screenings.get(r, {}).items()))
            for r in raters]


def panel_json(summary: PanelSummary) -> dict[str, Any]:
    """The panel for summary.json: counts only; free-text answers stay in the report."""
    return {
        "n_participants": summary.n_participants,
        "sentence": summary.sentence,
        "answered": dict(summary.answered),
        "questions": [{"id": q.id, "questionnaire": q.questionnaire, "type": q.kind,
                       "text": q.text, "n_answered": q.n_answered, "counts": dict(q.counts),
                       **({"min": min(q.values), "max": max(q.values)} if q.values else {})}
                      for q in summary.questions],
        "n_free_text": {k: len(v) for k, v in summary.free_text.items()},
        "screening": list(summary.screening),
        "failed_vision": list(summary.failed_vision),
    }


def answer_counts_rows(summary: PanelSummary) -> list[dict[str, Any]]:
    """One row per question with every answer's count: the report's panel table."""
    rows = []
    for q in summary.questions:
        parts = []
        if q.values:
            parts.append(f"{min(q.values):g}-{max(q.values):g} (median "
                         f"{float(np.median(q.values)):g}, n={len(q.values)})")
        parts += [f"{answer} {count}" for answer, count in q.counts.items()
                  if count or answer not in (PREFERRED_NOT, NOT_ANSWERED)]
        rows.append({"questionnaire": q.questionnaire, "question": q.text,
                     "answers (count)": " · ".join(parts)})
    return rows
