"""The presentation clock: frame index of each refresh, blank lengths, flip statistics and
the pacer of the no-vsync pilot mode."""

from __future__ import annotations

import itertools

import pytest

from study_app.clock import FlipPacer, FlipStats, blank_refreshes, frame_index


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


def test_a_long_freeze_counts_every_refresh_it_hid():
    """At 60 Hz, a 1 s freeze is one late flip (one 'dropped frame' by the 1.5-period rule)
    but hid 59 refreshes; 11 one-refresh hiccups hid 11. Re-queueing judged the first trial
    fine and the second broken; it now goes by the refreshes missed."""
    from session_store import PlannedTrial
    from study_app.app import needs_requeue
    from study_app.clock import FlipStats

    period = 1 / 60
    freeze = FlipStats(period)
    t = 0.0
    for step in [period] * 30 + [1.0] + [period] * 30:
        t += step
        freeze.add(t)
    hiccups = FlipStats(period)
    t = 0.0
    for k in range(60):
        t += 2 * period if k % 5 == 1 and k < 55 else period  # k = 1, 6, ..., 51: 11
        hiccups.add(t)
    assert (freeze.dropped_frames, freeze.missed_refreshes) == (1, 59)
    assert (hiccups.dropped_frames, hiccups.missed_refreshes) == (11, 11)
    trial = PlannedTrial(0, "S", "R", 1, False)
    assert needs_requeue(freeze.missed_refreshes, 10, trial)
    assert needs_requeue(hiccups.missed_refreshes, 10, trial)
    assert not needs_requeue(FlipStats(period).missed_refreshes, 10, trial)
