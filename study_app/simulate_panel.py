"""Simulated answers to the manifest's questionnaires, and simulated vision checks.

The distribution is fixed and documented so that a demo report's panel section is
predictable from the seed:

- numbers (age): a normal distribution with mean 33 and s.d. 9, rounded and clipped to the
  question's range;
- the demographics template's questions by their ids: ``gender`` male 0.70, female 0.25,
  non-binary 0.05; ``vision`` normal 0.6, corrected 0.4; ``colour_vision`` no 0.95,
  unsure 0.05; other single-choice questions uniformly over their options;
- multiple choice: each option with probability 0.4, within the question's bounds;
- Likert: a rounded normal around a per-question centre (uniform on 2.5..4.5 of a 5-point
  scale, scaled to other lengths) with s.d. 1;
- short text: one of a few fixed comments with probability 0.3, otherwise no answer;
- a questionnaire marked ``voluntary`` is answered by a participant with probability 0.65
  (13 of 20 in the CGVQM+D paper); every other one in full;
- a question offering "prefer not to say" gets it with probability 0.03.

Vision checks: every simulated participant passes, except the ones chosen to fail the colour
check (``SimulationOptions.colour_failures``), whose result says it was simulated. With
``on_fail: end`` a failing participant's session ends there, as in the player: the event
``ended_by_vision_check``, no questionnaire, no rating.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stimuli_manifests.panel import (
    PREFER_NOT_TO_SAY,
    Likert,
    MultipleChoice,
    Number,
    Panel,
    Questionnaire,
    SingleChoice,
    Text,
    check_answer,
)

VOLUNTARY_RESPONSE_RATE = 0.65
PREFER_NOT_RATE = 0.03
KNOWN_CHOICES: dict[str, dict[str, float]] = {
    "gender": {"male": 0.70, "female": 0.25, "non_binary": 0.05},
    "vision": {"normal": 0.6, "corrected": 0.4},
    "colour_vision": {"no": 0.95, "unsure": 0.05},
}
COMMENTS = ("Some pairs looked identical to me.", "The flicker in a few videos was tiring.",
            "Clear instructions, thank you.", "Hard to judge the very noisy ones.")


def likert_centres(panel: Panel, rng: np.random.Generator) -> dict[str, float]:
    """Each Likert question's centre as a share of its scale (drawn once per panel)."""
    return {q.id: float(rng.uniform(0.375, 0.875)) for qn in panel.questionnaires
            for q in qn.questions() if isinstance(q, Likert)}


def simulated_answer(question: Any, rng: np.random.Generator, centre: float = 0.6) -> Any:
    """One answer drawn from the documented distribution (valid for ``question``)."""
    if question.offers_prefer_not_to_say and rng.random() < PREFER_NOT_RATE:
        return PREFER_NOT_TO_SAY
    if isinstance(question, Number):
        value = float(np.clip(round(rng.normal(33.0, 9.0)), question.min, question.max))
        return value if not question.integer else int(value)
    if isinstance(question, SingleChoice):
        values = [o.value for o in question.options]
        known = KNOWN_CHOICES.get(question.id)
        if known and set(known) <= set(values):
            keys = list(known)
            return keys[int(rng.choice(len(keys), p=np.array(list(known.values()))))]
        return values[int(rng.integers(len(values)))]
    if isinstance(question, MultipleChoice):
        values = [o.value for o in question.options]
        chosen = [v for v in values if rng.random() < 0.4]
        top = len(values) if question.max_selected is None else question.max_selected
        while len(chosen) < question.min_selected:
            chosen.append(next(v for v in values if v not in chosen))
        return chosen[:top]
    if isinstance(question, Likert):
        n = len(question.points)
        return int(np.clip(round(rng.normal(1 + centre * (n - 1), 1.0)), 1, n))
    if isinstance(question, Text):
        return COMMENTS[int(rng.integers(len(COMMENTS)))] if rng.random() < 0.3 else None
    raise TypeError(f"unknown question type {type(question).__name__}")


def simulated_answers(questionnaire: Questionnaire, rng: np.random.Generator,
                      centres: dict[str, float]) -> list[tuple[int, str, Any]]:
    """(page, question id, answer) for one participant, checked by the one answer rule;
    empty when a voluntary questionnaire is skipped."""
    if questionnaire.voluntary and rng.random() >= VOLUNTARY_RESPONSE_RATE:
        return []
    out = []
    for page, p in enumerate(questionnaire.pages):
        for q in p.questions:
            value = check_answer(q, simulated_answer(q, rng, centres.get(q.id, 0.6)))
            if value is not None:
                out.append((page, q.id, value))
    return out


def simulated_colour_check(failed: bool) -> tuple[str, dict[str, Any]]:
    """(outcome, result) of a simulated colour-vision check."""
    return ("failed" if failed else "passed",
            {"test": "colour", "simulated": True, "passed": not failed,
             "details": {"simulated_deficiency": "deutan" if failed else None}})


def simulated_acuity_check() -> tuple[str, dict[str, Any]]:
    """(outcome, result) of a simulated contrast/acuity check: every simulated rater sees
    20/20 and Weber 0.063 (the simulation's raters differ in bias and consistency, not in
    eyesight)."""
    return ("passed", {"test": "acuity", "simulated": True, "passed": True,
                       "acuity": {"threshold_logmar": 0.0},
                       "contrast": {"threshold_weber": 0.063}})
