"""Viewing geometry from the card calibration (against a hand computation), the optotypes
(orientation, size and contrast read back from their pixels), what a display cannot draw,
and the trial plan."""

from __future__ import annotations

import math

import numpy as np
import pytest

from study_app.vision.acuity import (
    ORIENTATIONS,
    ContrastTooLowError,
    OptotypeTooSmallError,
    background_code,
    card_calibration,
    card_rect_px,
    grey_levels,
    logmar,
    optotype,
    size_arcmin,
    smallest_size_arcmin,
    snellen,
)
from study_app.vision.acuity_plan import (
    CONTRAST_LEVELS,
    HIGH_CONTRAST,
    acuity_plan,
    drawable_levels,
    showable_contrasts,
)
from study_app.vision.dichromacy import srgb_to_linear


def from_uint8(code: int) -> float:  # the IEC 61966-2-1 curve, through the colour module
    return float(srgb_to_linear(np.float64(code) / 255))


def test_geometry_matches_a_hand_computation():
    # 856 px over the card's 85.60 mm is 10 px/mm; at 57.3 cm one degree spans
    # 2 * 573 mm * tan(0.5 deg) = 10.0010 mm, so 100.01 px.
    g = card_calibration(856, 57.3)
    assert g.px_per_mm == pytest.approx(10.0)
    assert g.px_per_degree == pytest.approx(100.01, abs=0.01)
    assert g.px_per_arcmin == pytest.approx(100.01 / 60, abs=1e-3)
    # a 96 ppi display (3.78 px/mm) at 60 cm: 10.472 mm a degree, 39.59 px
    g = card_calibration(85.6 * 3.78, 60)
    assert g.px_per_degree == pytest.approx(39.585, abs=0.01)
    assert card_rect_px(856) == (856, 540)  # the ID-1 aspect, 85.60 x 53.98 mm
    assert set(g.to_dict()) == {"px_per_mm", "px_per_degree", "viewing_distance_cm"}


@pytest.mark.parametrize(("width", "distance", "message"), [
    (0, 60, "positive"), (-300, 60, "positive"), (math.nan, 60, "positive"),
    (320, 0, "positive"), (320, math.inf, "positive"),
    (320, 25, r"outside 30\.\.200 cm"), (320, 250, r"outside 30\.\.200 cm"),
    (40, 60, "no display has"), (5000, 60, "no display has"),
])
def test_silly_calibrations_are_refused_with_a_reason(width, distance, message):
    with pytest.raises(ValueError, match=message):
        card_calibration(width, distance)


def test_size_conventions():
    assert size_arcmin(0.0) == pytest.approx(5.0)  # 20/20: 1 arcmin strokes
    assert size_arcmin(1.0) == pytest.approx(50.0)
    assert logmar(10.0) == pytest.approx(math.log10(2))
    assert snellen(10.0) == "20/40" and snellen(5.0, 6) == "6/6"


def _dark(img: np.ndarray) -> np.ndarray:
    return img < (img.max() + img.min()) / 2


@pytest.mark.parametrize("orientation", ORIENTATIONS)
def test_landolt_c_opens_where_asked_and_has_the_asked_size(orientation):
    g = card_calibration(856, 57.3)  # 100 px a degree: a 30 arcmin C is 50 px, gap 10 px
    img = optotype("landolt_c", orientation, 30, 0.9, g, margin=0.5)
    assert img.dtype == np.uint8 and img.ndim == 2
    dark = _dark(img)
    rows, cols = np.flatnonzero(dark.any(axis=1)), np.flatnonzero(dark.any(axis=0))
    assert rows[-1] - rows[0] + 1 == pytest.approx(50, abs=1)
    assert cols[-1] - cols[0] + 1 == pytest.approx(50, abs=1)
    c = img.shape[0] / 2
    ring = {"right": (c, c + 20), "up": (c - 20, c), "left": (c, c - 20), "down": (c + 20, c)}
    for where, (y, x) in ring.items():
        assert dark[int(y), int(x)] == (where != orientation), where


@pytest.mark.parametrize("orientation", ORIENTATIONS)
def test_tumbling_e_points_where_asked(orientation):
    g = card_calibration(856, 57.3)
    dark = _dark(optotype("tumbling_e", orientation, 30, 0.9, g, margin=0.0))
    assert dark.shape == (50, 50)
    # the open side has three bars and two gaps; the spine's side is solid
    edge = {"right": dark[:, -3], "left": dark[:, 2], "up": dark[2, :], "down": dark[-3, :]}
    for side, line in edge.items():
        assert line.all() != (side == orientation), side


def test_contrast_is_weber_in_linear_light():
    bg, fg, shown = grey_levels(0.5)
    assert bg == background_code() == 188  # half the white luminance
    assert (from_uint8(fg) - from_uint8(bg)) / from_uint8(bg) == pytest.approx(-shown)
    assert shown == pytest.approx(0.5, abs=0.01)
    img = optotype("landolt_c", "up", 50, 0.5, card_calibration(856, 57.3))
    assert img.min() == fg and img.max() == bg
    light = grey_levels(0.25, "light")
    assert light[1] > light[0] and light[2] == pytest.approx(0.25, abs=0.01)
    with pytest.raises(ContrastTooLowError):
        grey_levels(0.002)
    with pytest.raises(ValueError, match="Weber contrast"):
        grey_levels(1.5)


def test_optotypes_too_small_for_the_display_are_reported_not_drawn():
    g = card_calibration(85.6 * 3.78, 60)  # ~40 px a degree: 1 px is 1.5 arcmin
    smallest = smallest_size_arcmin(g)
    assert smallest == pytest.approx(5 * 60 / 39.585, abs=0.01)  # 5 strokes of one pixel
    assert optotype("landolt_c", "left", smallest * 1.01, 0.9, g).shape[0] >= 7
    with pytest.raises(OptotypeTooSmallError, match=r"smallest it can draw is 7\.58 arcmin") as e:
        optotype("tumbling_e", "left", 5.0, 0.9, g)  # 20/20 needs 60 px a degree
    assert e.value.smallest_arcmin == pytest.approx(smallest)
    drawn, skipped = drawable_levels(g)
    assert drawn[-1] == 0.2 and skipped == [0.1, 0.0]


def test_plan_follows_the_seed_and_leaves_out_what_cannot_be_drawn():
    g = card_calibration(85.6 * 3.78, 60)
    plan = acuity_plan(g, 9, trials_per_level=5)
    acuity, contrast = plan.series("acuity"), plan.series("contrast")
    assert len(acuity) == 7 * 5 and acuity[0].logmar == 1.0 and acuity[-1].logmar == 0.2
    assert plan.undrawable_logmar == [0.1, 0.0] and plan.unshowable_contrast == []
    assert {t.contrast for t in acuity} == {HIGH_CONTRAST}
    assert [t.contrast for t in contrast[::5]] == list(CONTRAST_LEVELS)
    assert {t.logmar for t in contrast} == {0.8}
    assert [len(lv) for lv in plan.levels("acuity")] == [5] * 7
    assert [t.level for t in acuity] == sorted(t.level for t in acuity)
    assert plan == acuity_plan(g, 9, trials_per_level=5)
    assert [t.orientation for t in plan.trials] != [
        t.orientation for t in acuity_plan(g, 10).trials]
    assert {t.orientation for t in plan.trials} == set(ORIENTATIONS)
    for t in plan.trials[::5]:  # every planned optotype can be drawn
        optotype(t.kind, t.orientation, t.size_arcmin, t.contrast, g)
    with pytest.raises(ValueError, match="cannot draw"):
        acuity_plan(g, 1, logmar_levels=(0.0,))


def test_levels_too_large_for_the_window_are_left_out():
    g = card_calibration(856, 57.3)  # 100 px a degree: logMAR 1.0 is 83 px, 0.8 is 53 px
    drawn, _ = drawable_levels(g, max_size_px=60)
    assert drawn[0] == 0.8
    plan = acuity_plan(g, 1, max_size_px=60)
    assert plan.series("acuity")[0].logmar == 0.8
    with pytest.raises(ValueError, match="cannot draw"):
        acuity_plan(g, 1, max_size_px=40)  # the contrast series' optotypes are 53 px


def test_contrasts_8_bit_codes_cannot_show_are_left_out():
    shown, not_shown = showable_contrasts((0.5, 0.01, 0.004))
    assert shown == [0.5, 0.01] and not_shown == [0.004]
