"""The rating slider: geometry, no marker until touched, mouse and keyboard steps."""

from __future__ import annotations

import pytest

from study_app.slider import Slider


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
