"""What the answers to the contrast/acuity check mean, as the session records it.

A level passes with ``needed`` of its trials right (default 3 of 5: with four alternatives,
guessing does so with probability 0.104) and fails once that is out of reach, so a screen can
stop it early. A series' threshold is its last level passed with every easier level passed.

- The easiest level of each series is its control: anyone doing the task reads it. Missing
  a control gives ``inconclusive``, not a failure (a misunderstood task, a wrong key, a
  display that cannot show the stimuli).
- Otherwise a series fails when its threshold does not reach its criterion (acuity: logMAR
  0.3 by default, 20/40 or 6/12, a common screening cut-off; contrast: Weber 0.063, log
  contrast sensitivity 1.2, well below the 1.65 or more of normal vision on a Pelli-Robson
  chart, to leave room for an uncalibrated display). Any failed series fails the check.
- When the display could not draw the criterion level at the measured distance (strokes under
  a pixel) or show it in 8-bit codes, and every level it could show was passed, the outcome
  is ``inconclusive``: limited by the display, not by the eyes.

It is a screening on an uncalibrated display, never a diagnosis.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

from stimuli_manifests.panel import ACUITY_CRITERION_LOGMAR, CONTRAST_CRITERION_WEBER

from .acuity import Geometry, grey_levels, snellen
from .acuity_plan import AcuityPlan, OptotypeTrial, Series

Outcome = Literal["passed", "failed", "inconclusive"]
NEEDED_PER_LEVEL = 3
CRITERION_LOGMAR = ACUITY_CRITERION_LOGMAR
CRITERION_CONTRAST = CONTRAST_CRITERION_WEBER
RULE = ("a level passes with {needed} of its trials right; a series' threshold is its last "
        "level passed with every easier one; a missed easiest level is inconclusive; the check "
        "fails when acuity is worse than logMAR {logmar:g} or contrast worse than Weber "
        "{contrast:g}; inconclusive when the display could not show the criterion level")
NOTE = ("a screening on an uncalibrated display, not a diagnosis: it says what this "
        "participant saw on this screen at the stated distance")


@dataclass(frozen=True)
class OptotypeAnswer:
    """One optotype as shown and answered (``given``: right, up, left or down)."""

    trial: OptotypeTrial
    given: str
    ms: float

    @property
    def correct(self) -> bool:
        return self.given == self.trial.orientation


def level_outcome(correct: Sequence[bool], trials: int,
                  needed: int = NEEDED_PER_LEVEL) -> Literal["passed", "failed"] | None:
    """A level's outcome once it is decided (the screen then skips its remaining trials),
    None while it is open."""
    right = sum(bool(c) for c in correct)
    if right >= needed:
        return "passed"
    if len(correct) - right > trials - needed:
        return "failed"
    return None


def next_trial(plan: AcuityPlan, answers: Sequence[OptotypeAnswer],
               needed: int = NEEDED_PER_LEVEL) -> OptotypeTrial | None:
    """The trial to show after ``answers``: levels in order, each until it is decided, a
    series left after its first failed level; None when the check is done."""
    for name in ("acuity", "contrast"):
        for level in plan.levels(name):  # type: ignore[arg-type]
            marks = [a.correct for a in answers
                     if a.trial.series == name and a.trial.level == level[0].level]
            decided = level_outcome(marks, len(level), needed)
            if decided is None:
                return level[len(marks)]
            if decided == "failed":
                break
    return None


def most_trials(plan: AcuityPlan, answers: Sequence[OptotypeAnswer],
                needed: int = NEEDED_PER_LEVEL) -> int:
    """The most trials the whole check can still take, those shown included: the levels
    decided so far count what they showed, a series after a failed level counts nothing
    more, every open level all its planned trials (the count the participant sees)."""
    total = 0
    for name in ("acuity", "contrast"):
        for level in plan.levels(name):  # type: ignore[arg-type]
            marks = [a.correct for a in answers
                     if a.trial.series == name and a.trial.level == level[0].level]
            decided = level_outcome(marks, len(level), needed)
            total += len(level) if decided is None else len(marks)
            if decided == "failed":
                break
    return total


def _series(plan: AcuityPlan, name: Series, answers: Sequence[OptotypeAnswer],
            needed: int) -> list[dict[str, Any]]:
    """Per planned level of one series: what was shown, how many right, its outcome."""
    out = []
    for level in plan.levels(name):
        first = level[0]
        marks = [a.correct for a in answers
                 if a.trial.series == name and a.trial.level == first.level]
        out.append({"level": first.level, "logmar": first.logmar,
                    "size_arcmin": round(first.size_arcmin, 3),
                    "snellen": snellen(first.size_arcmin), "contrast": first.contrast,
                    "contrast_shown": round(grey_levels(first.contrast)[2], 4),
                    "planned": len(level), "shown": len(marks), "right": sum(marks),
                    "outcome": level_outcome(marks, len(level), needed) if marks else None})
    return out


def _threshold(levels: list[dict[str, Any]], key: str) -> float | None:
    best = None
    for lv in levels:
        if lv["outcome"] != "passed":
            break
        best = lv[key]
    return best


def _verdict(levels: list[dict[str, Any]], key: str, criterion: float,
             limited: bool) -> tuple[Outcome, str]:
    """One series' outcome and why: smaller values of ``key`` are harder levels."""
    threshold = _threshold(levels, key)
    if threshold is None:
        return "inconclusive", "the easiest level was not read"
    if threshold <= criterion + 1e-9:
        return "passed", "criterion reached"
    if limited and len(levels) and threshold == levels[-1][key]:
        return "inconclusive", "every level the display could show was read; it cannot " \
                               "show the criterion level"
    return "failed", "criterion not reached"


def score_acuity(plan: AcuityPlan, answers: Sequence[OptotypeAnswer],
                 geometry: Geometry | None = None, *,
                 criterion_logmar: float = CRITERION_LOGMAR,
                 criterion_contrast: float = CRITERION_CONTRAST,
                 needed: int = NEEDED_PER_LEVEL) -> tuple[Outcome, dict[str, Any]]:
    """(outcome, result) of a contrast/acuity check from the answers given, in order."""
    acuity = _series(plan, "acuity", answers, needed)
    contrast = _series(plan, "contrast", answers, needed)
    acuity_limited = not any(lv["logmar"] <= criterion_logmar + 1e-9 for lv in acuity)
    contrast_limited = not any(lv["contrast"] <= criterion_contrast + 1e-9 for lv in contrast)
    verdicts = {"acuity": _verdict(acuity, "logmar", criterion_logmar, acuity_limited),
                "contrast": _verdict(contrast, "contrast", criterion_contrast,
                                     contrast_limited)}
    outcomes = {name: v[0] for name, v in verdicts.items()}
    controls_read = all(s and s[0]["outcome"] == "passed" for s in (acuity, contrast))
    outcome: Outcome
    if not controls_read:
        outcome = "inconclusive"
    elif "failed" in outcomes.values():
        outcome = "failed"
    elif "inconclusive" in outcomes.values():
        outcome = "inconclusive"
    else:
        outcome = "passed"
    threshold = _threshold(acuity, "logmar")
    times = [a.ms for a in answers]
    return outcome, {
        "test": "acuity", "outcome": outcome, "passed": outcome == "passed",
        "rule": RULE.format(needed=f"{needed} of the planned", logmar=criterion_logmar,
                            contrast=criterion_contrast),
        "note": NOTE,
        "acuity": {"outcome": outcomes["acuity"], "reason": verdicts["acuity"][1],
                   "threshold_logmar": threshold,
                   "threshold_snellen": None if threshold is None
                   else next(lv["snellen"] for lv in acuity if lv["logmar"] == threshold),
                   "criterion_logmar": criterion_logmar, "limited_by_display": acuity_limited,
                   "not_drawable_logmar": plan.undrawable_logmar,
                   "too_large_logmar": plan.too_large_logmar, "levels": acuity},
        "contrast": {"outcome": outcomes["contrast"], "reason": verdicts["contrast"][1],
                     "threshold_weber": _threshold(contrast, "contrast"),
                     "threshold_weber_shown": _threshold(contrast, "contrast_shown"),
                     "criterion_weber": criterion_contrast,
                     "limited_by_display": contrast_limited,
                     "not_showable_weber": plan.unshowable_contrast, "levels": contrast},
        "geometry": None if geometry is None else geometry.to_dict(),
        "answers": [{"series": a.trial.series, "level": a.trial.level,
                     "expected": a.trial.orientation, "given": a.given, "ms": a.ms}
                    for a in answers],
        "median_ms": round(statistics.median(times), 1) if times else None,
    }
