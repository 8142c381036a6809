"""Scale anchoring: monotone, on 0..100, recovers a known map; alpha refit in closed form."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import expit

from cgvqm_core.calibration import anchoring_for, apply_anchor, fit_anchor, refit_alpha
from cgvqm_core.errors import CGVQMError


def _data(seed=0, n=200):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-150, 100, n)  # raw CGVQM scores are unbounded below
    truth = 10 + 85 * expit((q - 20) / 25)
    y = truth + rng.normal(0, 2, n)
    return q, y, truth


@pytest.mark.parametrize("method", ["logistic", "isotonic"])
def test_anchor_is_monotone_and_lands_on_0_100(method):
    q, y, _ = _data()
    a = fit_anchor(q, y, method)
    grid = np.linspace(-1e4, 1e4, 20001)
    out = apply_anchor(a, grid)
    assert (np.diff(out) >= 0).all()
    assert out.min() >= 0 and out.max() <= 100


def test_logistic_anchor_recovers_a_known_map():
    q, y, _ = _data()
    a = fit_anchor(q, y, "logistic")
    assert a["lo"] == pytest.approx(10, abs=2)
    assert a["hi"] == pytest.approx(95, abs=2)
    assert a["center"] == pytest.approx(20, abs=3)
    assert a["scale"] == pytest.approx(25, rel=0.15)
    grid = np.linspace(-150, 100, 50)
    np.testing.assert_allclose(apply_anchor(a, grid), 10 + 85 * expit((grid - 20) / 25), atol=2)


def test_isotonic_anchor_fits_better_than_the_mean():
    q, y, truth = _data(1)
    pred = apply_anchor(fit_anchor(q, y, "isotonic"), q)
    assert np.sqrt(np.mean((pred - truth) ** 2)) < 2.5


def test_anchor_is_increasing_even_when_scores_and_target_disagree():
    """A map fitted to anti-correlated data stays non-decreasing (flat), never inverts."""
    q, y, _ = _data(2)
    for method in ("logistic", "isotonic"):
        out = apply_anchor(fit_anchor(q, 100 - y, method), np.sort(q))
        assert (np.diff(out) >= -1e-9).all()
        assert np.ptp(out) < np.ptp(y) / 2


def test_refit_alpha_is_the_least_squares_solution():
    rng = np.random.default_rng(0)
    e = rng.uniform(0, 1, 50)
    y = 100 - 37.0 * e + rng.normal(0, 1, 50)
    alpha = refit_alpha(e, y)
    grid = np.linspace(30, 45, 3001)
    sse = [np.sum((100 - a * e - y) ** 2) for a in grid]
    assert alpha == pytest.approx(grid[int(np.argmin(sse))], abs=0.01)
    with pytest.raises(CGVQMError, match="zero feature error"):
        refit_alpha(np.zeros(5), y[:5])


def test_unknown_anchor_formats_are_refused():
    with pytest.raises(CGVQMError, match="not supported"):
        apply_anchor({"format": "cgvqm-anchor/2", "kind": "logistic"}, 1.0)


def test_anchoring_applies_only_to_the_pooling_it_was_fitted_for():
    q, y, _ = _data()
    prov = {"anchoring": fit_anchor(q, y, "logistic", pool="max")}
    assert anchoring_for(prov, "max") is prov["anchoring"]
    assert anchoring_for(prov, "mean") is None
    assert anchoring_for({}, "max") is None and anchoring_for(None, "max") is None
