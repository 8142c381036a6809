"""When the player offers a break: every N trials, but not in the last stretch."""

from __future__ import annotations

from study_app.breaks import break_due


def _breaks_offered(n_trials: int, every: int) -> list[int]:
    """After which trials (1-based) a session of ``n_trials`` offers a break."""
    since, at = 0, []
    for done in range(1, n_trials + 1):
        since += 1
        if break_due(since, every, n_trials - done):
            since = 0
            at.append(done)
    return at


def test_every_n_trials_but_none_just_before_the_end():
    assert _breaks_offered(240, 40) == [40, 80, 120, 160, 200]  # 40 left after the last
    assert _breaks_offered(130, 40) == [40, 80, 120]  # 10 left: a quarter of 40, still a break
    assert _breaks_offered(129, 40) == [40, 80]  # 9 left after 120: straight on to the end
    assert _breaks_offered(45, 40) == []


def test_never_after_the_last_trial_and_never_when_off():
    assert _breaks_offered(3, 1) == [1, 2]
    assert _breaks_offered(240, 0) == []
    assert not break_due(5, 5, 0)
