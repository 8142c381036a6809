"""The trial state machine, driven by synthetic flip times and commands (no display)."""

from __future__ import annotations

import math

import pytest

from study_app.slider import Slider
from study_app.trial import RATE, VIEW, Command, TrialMachine

HZ = 60.0
PERIOD = 1 / HZ


def _machine(**kw) -> TrialMachine:
    slider = Slider(x0=100, x1=1100, y=500)
    args = dict(fps=30.0, refresh_hz=HZ, frames=30, slider=slider, blank_seconds=0.5,
                min_view_s=None, cpu_clock=lambda: 0.0, wall_clock=lambda: "T0")
    args.update(kw)
    return TrialMachine(**args)


def _run(m: TrialMachine, t0: float, n: int, step: float = PERIOD) -> tuple[float, list]:
    """Present ``n`` refreshes starting at ``t0``; returns the next time and what showed."""
    shown = []
    t = t0
    for _ in range(n):
        shown.append(m.next_frame())
        m.flipped(t)
        t += step
    return t, shown


def test_frames_follow_the_presentation_clock_and_loop():
    m = _machine()
    _, shown = _run(m, 0.0, 70)
    # 30 fps on 60 Hz: each frame twice, then the loop starts again at frame 0.
    assert [i for _, i in shown[:6]] == [0, 0, 1, 1, 2, 2]
    assert shown[60] == ("test", 0)
    assert {c for c, _ in shown} == {"test"}


def test_switch_shows_the_blank_for_its_refreshes_then_the_co_located_frame():
    m = _machine()
    t, _ = _run(m, 0.0, 10)
    assert m.command(Command("switch"), t - 0.001)[0].info == {"state": "switch",
                                                               "to": "reference"}
    t, shown = _run(m, t, 40)
    contents = [c for c, _ in shown]
    assert contents[:30] == ["blank"] * 30  # round(0.5 s x 60 Hz)
    assert contents[30] == "reference"
    # The clock kept running during the blank: the reference shows frame (10 + 30) // 2.
    assert shown[30][1] == (10 + 30) // 2
    assert m.blank_refresh_counts == [30]
    assert m.switch_latencies_ms == pytest.approx([1000 * (30 * PERIOD + 0.001)], abs=1e-6)
    # A second switch during a blank is ignored (no double toggles).
    m.command(Command("switch"), t)
    m.command(Command("switch"), t)
    assert m.n_toggles == 2


def test_time_on_each_video_excludes_the_blank():
    m = _machine()
    t, _ = _run(m, 0.0, 61)  # 60 intervals on the test video
    m.command(Command("switch"), t)
    t, _ = _run(m, t, 30 + 60)  # blank, then 60 intervals of reference
    assert m.ms_on["test"] == pytest.approx(1000.0 + 1000 * PERIOD, abs=1e-6)
    assert m.ms_on["reference"] == pytest.approx(1000 * 59 * PERIOD, abs=1e-6)
    assert m.viewing_s == pytest.approx((61 + 90 - 1) * PERIOD, abs=1e-9)


def test_dropped_flips_advance_the_clock_and_count():
    m = _machine()
    t, _ = _run(m, 0.0, 10)
    t += 2 * PERIOD  # two refreshes missed before this flip
    m.next_frame()
    m.flipped(t)
    assert m.stats.dropped_frames == 1
    assert m.n == 13  # 10 refreshes, then 3 for the late flip
    assert m.next_frame()[1] == 13 // 2


def test_rating_needs_the_minimum_viewing_time_and_a_set_slider():
    m = _machine(min_view_s=1.0)
    t, _ = _run(m, 0.0, 30)  # 0.5 s
    assert [a.name for a in m.command(Command("rate"), t)] == ["notice"]
    assert m.notice_active(t + 1.0) and not m.notice_active(t + 2.5)
    assert m.phase == VIEW
    t, _ = _run(m, t, 31)
    assert [a.name for a in m.command(Command("rate"), t)] == ["rating_opened"]
    assert m.phase == RATE
    # Submitting with no marker set is refused; the marker appears only when touched.
    assert [a.name for a in m.command(Command("submit"), t)] == ["notice"]
    assert m.notice_text() == "Set the slider first"
    assert m.slider.value is None
    m.command(Command("press", x=800, y=505), t + 0.2)
    m.command(Command("drag", x=850), t + 0.3)
    m.command(Command("release"), t + 0.35)
    assert m.slider.value == pytest.approx(75.0)
    out = m.command(Command("submit"), t + 0.5)
    assert [a.name for a in out] == ["submitted"]
    res = out[0].result
    assert res.rating == pytest.approx(75.0)
    assert res.rt_ms == pytest.approx(1000 * (t + 0.5))
    assert res.slider_first_move_ms == pytest.approx(1000 * (t + 0.2))
    assert res.n_toggles == 0 and res.ms_on_reference == 0
    assert res.details["blank_target_refreshes"] == 30


def test_rating_screen_keys_and_back_to_the_videos():
    m = _machine(min_view_s=0.0)
    _run(m, 0.0, 2)
    m.command(Command("rate"), 0.1)
    m.command(Command("step", direction=1), 0.2)  # first key press: the middle
    m.command(Command("step", direction=1, coarse=True), 0.3)
    m.command(Command("step", direction=-1), 0.4)
    assert m.slider.value == pytest.approx(59.0)
    assert [a.name for a in m.command(Command("back"), 0.5)] == ["viewing_resumed"]
    assert m.phase == VIEW
    # Flips while rating do not count as viewing time or presentation intervals.
    m.command(Command("rate"), 0.6)
    before = (m.viewing_s, m.stats.frames_presented)
    m.flipped(0.7)
    m.flipped(0.8)
    assert (m.viewing_s, m.stats.frames_presented) == before
    assert [a.name for a in m.command(Command("pause"), 0.9)] == ["pause"]


def test_rating_opens_only_outside_the_blank():
    m = _machine(min_view_s=0.1)
    t, _ = _run(m, 0.0, 12)
    m.command(Command("switch"), t)
    t, _ = _run(m, t, 5)
    assert m.in_blank
    assert [a.name for a in m.command(Command("rate"), t)] == ["notice"]


def test_a_gap_that_is_no_presentation_interval_is_not_a_dropped_frame():
    m = _machine()
    t, _ = _run(m, 0.0, 5)
    m.next_frame()
    m.flipped(t + 0.5, chained=False)  # e.g. a screenshot was read back before this flip
    assert m.stats.dropped_frames == 0


def test_result_without_a_rating_is_nan():
    m = _machine()
    assert math.isnan(m.result(0.0).rating)
