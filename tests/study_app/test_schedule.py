"""The order of trials: seeded schedules without immediate repeats, practice picks, and when
a trial with dropped frames is re-queued."""

from __future__ import annotations

import itertools
from collections import Counter

import pytest

from session_store.errors import StudyError
from study_app.schedule import ScheduleItem, make_schedule, participant_seed, pick_practice


def items(n):
    return [ScheduleItem(f"S{i:02d}", f"R{i % 3}", i % 5 == 0) for i in range(n)]


@pytest.mark.parametrize(("n", "reps"), [(2, 3), (3, 3), (80, 3), (7, 1), (5, 10)])
def test_schedule_counts_and_no_immediate_repeats(n, reps):
    for seed in range(5):
        plan = make_schedule(items(n), reps, seed)
        ids = [p.stimulus for p in plan]
        assert Counter(ids) == {f"S{i:02d}": reps for i in range(n)}
        assert all(a != b for a, b in itertools.pairwise(ids))
        assert [p.index for p in plan] == list(range(n * reps))
        for p in plan:  # repetition k is the k-th appearance
            assert p.repetition == ids[: p.index + 1].count(p.stimulus)


def test_schedule_is_seeded():
    a = make_schedule(items(20), 3, 11)
    assert a == make_schedule(items(20), 3, 11)
    assert a != make_schedule(items(20), 3, 12)
    assert participant_seed("s", "P01") == participant_seed("s", "P01")
    assert participant_seed("s", "P01") != participant_seed("s", "P02")


def test_schedule_refuses_impossible_and_empty():
    with pytest.raises(StudyError, match="twice in a row"):
        make_schedule(items(1), 3, 0)
    assert len(make_schedule(items(1), 1, 0)) == 1
    with pytest.raises(StudyError):
        make_schedule([], 3, 0)


def test_practice_picks_distinct():
    picks = pick_practice(items(10), 3, 5)
    assert len({p.id for p in picks}) == 3
    assert pick_practice(items(10), 0, 5) == []


def test_requeue_policy():
    from session_store import PlannedTrial
    from study_app.app import needs_requeue

    first = PlannedTrial(3, "S", "R", 1, False)
    again = PlannedTrial(9, "S", "R", 1, False, requeue_of=3)
    assert needs_requeue(11, 10, first) and not needs_requeue(10, 10, first)
    assert not needs_requeue(500, 10, again)  # re-queued once at most
    assert not needs_requeue(500, -1, first)  # disabled
    assert needs_requeue(1, 0, first)
