"""The contrast/acuity rule, from simulated observers whose true thresholds are known: the
trial sequence (levels stop once decided), the thresholds found, and the outcome, including
the display-limited and the misunderstood-task cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom

from study_app.vision.acuity import ORIENTATIONS, card_calibration
from study_app.vision.acuity_plan import acuity_plan
from study_app.vision.acuity_scoring import (
    NEEDED_PER_LEVEL,
    OptotypeAnswer,
    level_outcome,
    next_trial,
    score_acuity,
)

SHARP = card_calibration(856, 57.3)  # 100 px a degree: every level drawable
COARSE = card_calibration(85.6 * 2.0, 60)  # 2 px/mm: 1 px is 2.9 arcmin, logMAR 0.5 at best


def _observe(plan, *, logmar: float, weber: float, rng=None, misses_control=False):
    """Run the check with an observer who reads every optotype at least ``logmar`` large and
    ``weber`` strong, and gets the others wrong (or guesses, with ``rng``)."""
    answers: list[OptotypeAnswer] = []
    while (t := next_trial(plan, answers)) is not None:
        sees = t.logmar >= logmar - 1e-9 and t.contrast >= weber - 1e-9
        if misses_control:
            sees = False
        if sees:
            given = t.orientation
        elif rng is not None:
            given = ORIENTATIONS[int(rng.integers(4))]
        else:
            given = next(o for o in ORIENTATIONS if o != t.orientation)
        answers.append(OptotypeAnswer(t, given, 800.0))
    return answers


def test_guessing_passes_a_level_one_time_in_ten():
    assert binom.sf(NEEDED_PER_LEVEL - 1, 5, 0.25) == pytest.approx(0.104, abs=5e-4)
    assert level_outcome([True, True, True], 5) == "passed"
    assert level_outcome([False, False, False], 5) == "failed"
    assert level_outcome([True, False, True, False], 5) is None
    assert level_outcome([True, False, True, False, True], 5) == "passed"
    assert level_outcome([True, False, False, True, False], 5) == "failed"


def test_normal_vision_passes_with_three_trials_a_level():
    plan = acuity_plan(SHARP, 5)
    answers = _observe(plan, logmar=0.0, weber=0.032)
    assert len(answers) == 9 * 3 + 5 * 3  # every level decided after three right answers
    outcome, result = score_acuity(plan, answers, SHARP)
    assert outcome == "passed" and result["passed"]
    assert result["acuity"]["threshold_logmar"] == 0.0
    assert result["acuity"]["threshold_snellen"] == "20/20"
    assert result["contrast"]["threshold_weber"] == 0.032
    assert result["geometry"]["px_per_degree"] == pytest.approx(100.01, abs=0.01)
    assert [a["expected"] for a in result["answers"]] == [a.trial.orientation for a in answers]


def test_poor_acuity_fails_and_the_series_stops_at_the_first_failed_level():
    plan = acuity_plan(SHARP, 6)
    answers = _observe(plan, logmar=0.5, weber=0.032)
    acuity_shown = [a for a in answers if a.trial.series == "acuity"]
    # 1.0 .. 0.5 passed in three each, 0.4 failed after three wrong, nothing smaller shown
    assert len(acuity_shown) == 4 * 3 + 3
    assert min(a.trial.logmar for a in acuity_shown) == 0.4
    outcome, result = score_acuity(plan, answers, SHARP)
    assert outcome == "failed"
    assert result["acuity"]["outcome"] == "failed"
    assert result["acuity"]["threshold_logmar"] == 0.5
    assert result["contrast"]["outcome"] == "passed"  # 31.5 arcmin optotypes still read
    levels = result["acuity"]["levels"]
    assert [lv["outcome"] for lv in levels] == ["passed"] * 4 + ["failed"] + [None] * 4


def test_poor_contrast_sensitivity_fails_on_its_own():
    plan = acuity_plan(SHARP, 7)
    outcome, result = score_acuity(plan, _observe(plan, logmar=0.0, weber=0.125), SHARP)
    assert outcome == "failed"
    assert (result["acuity"]["outcome"], result["contrast"]["outcome"]) == ("passed", "failed")
    assert result["contrast"]["threshold_weber"] == 0.125
    # a looser criterion set by the experimenter passes the same answers
    assert score_acuity(plan, _observe(plan, logmar=0.0, weber=0.125), SHARP,
                        criterion_contrast=0.125)[0] == "passed"


def test_a_missed_control_is_inconclusive_not_a_failure():
    plan = acuity_plan(SHARP, 8)
    outcome, result = score_acuity(plan, _observe(plan, logmar=0, weber=0,
                                                  misses_control=True), SHARP)
    assert outcome == "inconclusive"
    assert result["acuity"]["reason"] == "the easiest level was not read"


def test_a_display_that_cannot_draw_the_criterion_is_inconclusive_when_all_else_is_read():
    plan = acuity_plan(COARSE, 9)
    assert plan.undrawable_logmar == [0.4, 0.3, 0.2, 0.1, 0.0]
    outcome, result = score_acuity(plan, _observe(plan, logmar=0.0, weber=0.032), COARSE)
    assert outcome == "inconclusive"
    assert result["acuity"]["limited_by_display"] is True
    assert result["acuity"]["threshold_logmar"] == 0.5
    assert "cannot show the criterion" in result["acuity"]["reason"]
    # someone who misses a drawable level on that display still fails
    outcome, _ = score_acuity(plan, _observe(plan, logmar=0.6, weber=0.032), COARSE)
    assert outcome == "failed"


def test_guessing_almost_never_passes():
    passed = 0
    for seed in range(300):
        plan = acuity_plan(SHARP, seed)
        answers = _observe(plan, logmar=9, weber=9, rng=np.random.default_rng(seed))
        passed += score_acuity(plan, answers, SHARP)[0] == "passed"
    # six acuity levels (1.0 .. 0.3) and four contrast levels at 0.104 each: about 1e-10
    assert passed == 0
