"""Error-map visualisation: colour map stops, tone mapping (with upstream's typo fixed)."""

from __future__ import annotations

import numpy as np

from cgvqm_core.emap import ToneCurve, colourise, fit_tone_curve
from cgvqm_core.stream import ArraySource, Geometry


def test_colour_map_stops():
    tone = np.full((1, 1, 5), 0.5)
    errs = np.array([[[0.0, 25.0, 50.0, 100.0, 1000.0]]])
    rgb = colourise(errs, tone)[0, 0]
    # blue stop (0.2, 0.2, 1) divided by its luminance 0.257749 (+1e-4), times 0.5, clipped
    s = 0.5 / (0.2 * 0.212656 + 0.2 * 0.715158 + 1.0 * 0.072186 + 1e-4)
    np.testing.assert_array_equal(rgb[0], (np.clip([0.2 * s, 0.2 * s, 1.0 * s], 0, 1) * 255)
                                  .astype(np.uint8))
    red = 0.5 / (1.0 * 0.212656 + 0.2 * 0.715158 + 0.2 * 0.072186 + 1e-4)
    expect_red = (np.clip([red, 0.2 * red, 0.2 * red], 0, 1) * 255).astype(np.uint8)
    np.testing.assert_array_equal(rgb[3], expect_red)
    np.testing.assert_array_equal(rgb[4], expect_red)  # errors above 100 saturate
    assert rgb[1][1] > rgb[1][0] and rgb[2][1] > rgb[2][2]  # cyan, then green


def test_low_contrast_tone_mapping_is_done_right():
    """A flat grey video: upstream's 1e03 typo would give (b/1000 - b_min)*0.6 + 0.2."""
    frames = np.full((3, 8, 8, 3), 100, np.uint8)
    geom = Geometry(3, 8, 8, 3.0, 4)
    curve = fit_tone_curve(ArraySource(frames, 3.0, "grey"), geom)
    assert curve.curve is None
    np.testing.assert_allclose(curve(frames), 0.2)  # (b - b_min)/(0 + 1e-3)*0.6 + 0.2


def test_histogram_tone_curve_is_monotone_and_in_range():
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (4, 16, 16, 3), dtype=np.uint8)
    curve = fit_tone_curve(ArraySource(frames, 4.0, "noise"), Geometry(4, 16, 16, 4.0, 4))
    assert isinstance(curve, ToneCurve) and curve.curve is not None
    assert np.all(np.diff(curve.curve) >= 0)
    t = curve(frames)
    assert t.min() >= 0.2 - 1e-6 and t.max() <= 0.8 + 1e-6
    # brighter pixels never get a darker tone
    lum = frames.astype(np.float64) @ [0.212656, 0.715158, 0.072186]
    order = np.argsort(lum.ravel())
    assert np.all(np.diff(t.ravel()[order]) >= -1e-9)
