"""Clock / frame-index mapping, schedule constraints, slider geometry."""

from __future__ import annotations

import itertools
from collections import Counter

import pytest

from session_store.errors import StudyError
from study_app.clock import FlipPacer, FlipStats, blank_refreshes, frame_index
from study_app.schedule import ScheduleItem, make_schedule, participant_seed, pick_practice
from study_app.slider import Slider

# -- clock -------------------------------------------------------------------------------


def test_frame_index_30fps_on_60hz_repeats_each_frame_twice():
    got = [frame_index(n, 30, 60, 90) for n in range(184)]
    assert got[:6] == [0, 0, 1, 1, 2, 2]
    assert got[178:184] == [89, 89, 0, 0, 1, 1]  # loops after 3 s = 180 refreshes


def test_frame_index_60fps_on_60hz_and_ntsc_rates():
    assert [frame_index(n, 60, 60, 5) for n in range(7)] == [0, 1, 2, 3, 4, 0, 1]
    # 59.94 Hz display, 29.97 fps video: exactly every second refresh, no drift over an hour.
    n = 60 * 60 * 59940 // 1000 * 2
    assert frame_index(n, 30000 / 1001, 60000 / 1001, 10**9) == n // 2
    # 30 fps on 144 Hz: frame k starts at refresh ceil(k * 4.8)
    assert frame_index(4, 30, 144, 90) == 0 and frame_index(5, 30, 144, 90) == 1
    assert frame_index(10, 30, 144, 90) == 2  # 10 * 30 / 144 = 2.08


def test_frame_index_without_loop_holds_last_frame():
    assert frame_index(1000, 60, 60, 10, loop=False) == 9


def test_blank_refreshes_rounds():
    assert blank_refreshes(0.5, 60) == 30
    assert blank_refreshes(0.5, 144) == 72
    assert blank_refreshes(0.5, 59.94) == 30  # 29.97 -> 30


def test_flip_stats_counts_intervals_over_one_and_a_half_periods():
    stats = FlipStats(period_s=1 / 60)
    t = 0.0
    for dt in [0, 1 / 60, 1 / 60, 2 / 60, 1 / 60, 0.0251, 0.0249]:
        t += dt
        stats.add(t)
    assert stats.frames_presented == 7
    assert stats.dropped_frames == 2  # 33.3 ms and 25.1 ms exceed 25.0 ms; 24.9 does not
    assert stats.max_interval_ms == pytest.approx(2000 / 60)


def test_pacer_holds_period_with_fake_clock():
    now = [0.0]

    def clock():
        return now[0]

    def sleep(s):
        now[0] += s

    def spin_clock():
        now[0] += 0.0001  # the busy-wait advances time a little per call
        return now[0]

    pacer = FlipPacer(60, clock=spin_clock, sleep=sleep, spin_s=0.001)
    slots = [pacer.wait() for _ in range(5)]
    assert [round((b - a) * 60, 6) for a, b in itertools.pairwise(slots)] == [1.0] * 4
    now[0] += 0.1  # the caller stalls for 6 periods
    late = pacer.wait()
    assert late >= now[0] - 1 / 60 and (late - slots[0]) * 60 == pytest.approx(
        round((late - slots[0]) * 60))
    assert clock() >= late


# -- schedule ----------------------------------------------------------------------------


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


# -- slider ------------------------------------------------------------------------------


def make_slider():
    return Slider(x0=100, x1=500, y=300, labels=[(0, "Very annoying"), (25, "Annoying"),
                                                (50, "Slightly"), (75, "Perc."), (100, "Imp.")])


def test_slider_geometry():
    s = make_slider()
    assert s.value_at(100) == 0 and s.value_at(500) == 100 and s.value_at(300) == 50
    assert s.value_at(199) == pytest.approx(24.75)
    assert s.value_at(-50) == 0 and s.value_at(900) == 100
    assert s.x_of(75) == 400
    assert [x for x, _ in s.label_positions()] == [100, 200, 300, 400, 500]


def test_slider_no_marker_until_touched_and_click_drag():
    s = make_slider()
    assert not s.is_set and s.value is None
    assert not s.press(300, 400, now=1.0)  # far below the track: ignored
    assert not s.is_set and s.first_touch is None
    assert s.press(350, 310, now=2.5)
    assert s.value == pytest.approx(62.5) and s.first_touch == 2.5
    s.drag(140)
    assert s.value == pytest.approx(10)
    s.release()
    s.drag(500)
    assert s.value == pytest.approx(10)  # not dragging any more
    s.press(120, 300, now=9.0)
    assert s.first_touch == 2.5  # first touch stays the first


def test_slider_keys_fine_and_coarse_and_clamped():
    s = make_slider()
    s.key_step(+1, coarse=False, now=3.0)
    assert s.value == 50 and s.first_touch == 3.0
    s.key_step(+1, coarse=False, now=3.1)
    s.key_step(+1, coarse=True, now=3.2)
    assert s.value == 61
    for _ in range(10):
        s.key_step(+1, coarse=True, now=4)
    assert s.value == 100
    s.key_step(-1, coarse=False, now=5)
    assert s.value == 99


def test_requeue_policy():
    from session_store import PlannedTrial
    from study_app.app import needs_requeue

    first = PlannedTrial(3, "S", "R", 1, False)
    again = PlannedTrial(9, "S", "R", 1, False, requeue_of=3)
    assert needs_requeue(11, 10, first) and not needs_requeue(10, 10, first)
    assert not needs_requeue(500, 10, again)  # re-queued once at most
    assert not needs_requeue(500, -1, first)  # disabled
    assert needs_requeue(1, 0, first)
