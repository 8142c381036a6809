"""Pre-flight checks: pure functions over measured values; messages say what to change on
the computer (never a command-line option)."""

from __future__ import annotations

import numpy as np
import pytest

from session_store.errors import StudyError
from stimuli_manifests import DisplayRequirements
from study_app.display import (
    DPI_PER_MONITOR_AWARE,
    DPI_SYSTEM_AWARE,
    DPI_UNAWARE,
    windows_stretches,
)
from study_app.preflight import (
    Monitor,
    PixelGeometry,
    check_decode_speed,
    check_memory,
    check_pixel_mapping,
    check_refresh,
    check_screen,
    raise_for_failures,
)
from study_app.vsync import estimate_refresh

REQ = DisplayRequirements()  # 1920x1080, 59 Hz
ONE = (Monitor(0, "DELL U2720Q", (0, 0, 1920, 1080)),)
TWO = (Monitor(0, "Built-in Retina Display", (0, 0, 1920, 1080)),
       Monitor(1, "LG HDR 4K", (1920, 0, 2560, 1440)))


def _no_flag(message: str) -> None:
    assert "--" not in message, message


def test_screen_size():
    c = check_screen(1366, 768, REQ, monitor="Laptop panel")
    assert not c.ok and "1366x768" in c.message and "1920x1080" in c.message
    assert "scaling to 100%" in c.message and "Laptop panel" in c.message
    _no_flag(c.message)
    assert check_screen(2560, 1440, REQ).ok


def _est(hz, n=120):
    return estimate_refresh(np.arange(n) / hz)


def test_refresh_needs_vsync_unless_the_experimenter_runs_a_pilot():
    no_vsync = estimate_refresh(np.cumsum(np.full(90, 0.0005)))
    c = check_refresh(no_vsync, REQ, paced_pilot=False)
    assert not c.ok and "vertical sync" in c.message and "graphics driver" in c.message
    _no_flag(c.message)
    c = check_refresh(no_vsync, REQ, paced_pilot=True, paced_hz=60)
    assert c.ok and c.warning and c.value["timing_mode"] == "paced-pilot"
    assert c.value["vsync"] is False and c.value["hz"] == 60.0


def test_refresh_rate_measured_from_vsync_flips():
    c = check_refresh(_est(60.0), REQ, paced_pilot=False)
    assert c.ok and c.value["hz"] == pytest.approx(60.0, abs=0.01)
    assert c.value["timing_mode"] == "vsync"
    c = check_refresh(_est(30.0), REQ, paced_pilot=False)
    assert not c.ok and "30.0 Hz" in c.message and "60 Hz or more" in c.message
    _no_flag(c.message)
    assert check_refresh(_est(144.0), REQ, paced_pilot=False).ok


def test_variable_or_busy_refresh_fails_with_what_to_turn_off():
    rng = np.random.default_rng(0)
    vrr = estimate_refresh(np.cumsum(rng.uniform(1 / 144, 1 / 48, 120)))
    c = check_refresh(vrr, REQ, paced_pilot=False)
    assert not c.ok and "variable refresh" in c.message and "FreeSync" in c.message
    times = list(np.arange(200) / 60.0)
    busy = estimate_refresh([t for i, t in enumerate(times) if i % 9 != 5])  # 22 late flips
    c = check_refresh(busy, REQ, paced_pilot=False)
    assert not c.ok and "close other programs" in c.message


def test_pixel_mapping_one_to_one():
    geom = PixelGeometry((1920, 1080), (1920, 1080), ONE, (0, 0), 0, 1.0)
    c = check_pixel_mapping(geom, (1024, 1024))
    assert c.ok and "DELL U2720Q" in c.message


def test_retina_framebuffer_is_one_to_one_in_its_own_pixels():
    geom = PixelGeometry((1440, 900), (2880, 1800), (Monitor(0, "Retina", (0, 0, 1440, 900)),),
                         (0, 0), 0, 2.0)
    assert check_pixel_mapping(geom, (1024, 1024)).ok


@pytest.mark.parametrize("scale", [1.25, 1.5])
def test_fractional_scaling_fails(scale):
    # A framebuffer that is scaled by a fraction (e.g. XWayland or a scaled macOS mode).
    w, h = 1536, 864
    geom = PixelGeometry((w, h), (round(w * scale), round(h * scale)), ONE, (0, 0), 0)
    c = check_pixel_mapping(geom, (1024, 1024))
    assert not c.ok and f"{round(scale * 100)}%" in c.message and "100%" in c.message
    _no_flag(c.message)
    # Windows stretches the window of a DPI-unaware process.
    geom = PixelGeometry((1536, 864), (1536, 864), ONE, (0, 0), 0, scale, os_stretches=True)
    c = check_pixel_mapping(geom, (1024, 1024))
    assert not c.ok and f"{round(scale * 100)}%" in c.message and "DELL U2720Q" in c.message


def test_windows_dpi_awareness_decides_stretching():
    assert not windows_stretches(DPI_PER_MONITOR_AWARE, 1.5, 1.5)
    assert windows_stretches(DPI_UNAWARE, 1.25, 1.25)
    assert not windows_stretches(DPI_UNAWARE, 1.0, 1.0)
    assert not windows_stretches(DPI_SYSTEM_AWARE, 1.25, 1.25)
    assert windows_stretches(DPI_SYSTEM_AWARE, 1.5, 1.0)  # moved to a scaled second monitor
    assert windows_stretches(None, 1.25, None)


def test_window_on_a_second_monitor_or_across_two_fails():
    on_second = PixelGeometry((2560, 1440), (2560, 1440), TWO, (1920, 0), 1, 1.0)
    c = check_pixel_mapping(on_second, (1024, 1024))
    assert not c.ok and "LG HDR 4K" in c.message and "main display" in c.message
    _no_flag(c.message)
    # Without SDL's display index the window's position decides.
    by_position = PixelGeometry((1280, 1024), (1280, 1024), TWO, (2200, 100), None)
    assert by_position.monitor().name == "LG HDR 4K"
    across = PixelGeometry((1280, 1024), (1280, 1024), TWO, (1500, 0), None, 1.0)
    c = check_pixel_mapping(across, (64, 64))
    assert not c.ok and "across two monitors" in c.message


def test_video_must_fit_with_its_label():
    geom = PixelGeometry((1280, 720), (1280, 720), ONE, (0, 0), 0)
    c = check_pixel_mapping(geom, (1024, 1024))
    assert not c.ok and "do not fit" in c.message
    geom = PixelGeometry((1024, 1024), (1024, 1024), ONE, (0, 0), 0)
    c = check_pixel_mapping(geom, (1024, 1024), fits_with_label=False)
    assert not c.ok and "no room" in c.message


def test_memory_and_decode_speed():
    c = check_memory(4 * 10**9, 1 * 10**9)  # in the GB a participant's computer shows
    assert not c.ok and "1.0 GB" in c.message and "4.0 GB" in c.message
    assert "24 MB" in check_memory(24 * 10**6, 8 * 10**9).message
    assert "the videos load fast enough (0.37 s per pair)" in check_decode_speed(0.37).message
    assert check_memory(1, None).ok
    c = check_decode_speed(25.0)
    assert not c.ok and "25.0 s" in c.message and "faster computer" in c.message
    with pytest.raises(StudyError, match="screen_size: the screen shows 1366x768") as info:
        raise_for_failures([check_screen(1366, 768, REQ), check_decode_speed(1.0)])
    _no_flag(str(info.value))
