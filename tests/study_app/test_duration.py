"""The session length told to participants before they start."""

from __future__ import annotations

from study_app.duration import describe_duration, estimate_minutes


def test_paper_design_brackets_the_reported_duration():
    """CGVQM+D: 80 stimuli x 3 repetitions of 3 s loops took participants 60-90 minutes."""
    low, high = estimate_minutes(240, 3.0, 0.5)
    assert low <= 60 and high >= 85 and high <= 100


def test_scales_with_trials_and_loop_length():
    assert estimate_minutes(120, 3.0, 0.5)[1] < estimate_minutes(240, 3.0, 0.5)[1]
    assert estimate_minutes(240, 6.0, 0.5)[0] > estimate_minutes(240, 3.0, 0.5)[0]
    assert estimate_minutes(0, 3.0, 0.5) == (0, 0)


def test_wording():
    assert describe_duration(3, 1.0, 0.5) == "about 1 minute (3 trials), plus the breaks you take"
    assert describe_duration(240, 3.0, 0.5).startswith("about 50-90 minutes (240 trials)")
