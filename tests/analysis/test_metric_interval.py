"""The metric intervals' orientation: with few stimuli the resamples' PLCCs crowd towards 1
(a refitted logistic overfits resamples that repeat stimuli), and the basic interval
mirrored that long tail into a lower bound far below every resample."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.metrics import _interval


def _skewed_resamples(n: int = 1001) -> np.ndarray:
    """PLCCs with a long tail towards 1, sorted so that the quantiles are order statistics."""
    rng = np.random.default_rng(3)
    z = np.concatenate([rng.normal(1.6, 0.12, n - 120), rng.uniform(2.0, 3.0, 120)])
    return np.sort(np.tanh(z))


def test_without_bias_the_interval_is_the_resamples_own_range():
    boot = _skewed_resamples()
    mid = float(np.percentile(boot, 50))  # an order statistic (index 500 of 1001)
    lo, hi = _interval(mid, mid, boot, "corr")
    # np.percentile on the PLCCs themselves: z is monotone, and 2.5/97.5 % of 1001 values
    # fall on order statistics, so no interpolation separates the two scales
    assert lo == pytest.approx(np.percentile(boot, 2.5), abs=1e-12)
    assert hi == pytest.approx(np.percentile(boot, 97.5), abs=1e-12)
    # the basic interval would have mirrored the long upper tail below every resample
    z = np.arctanh(boot)
    basic_lo = np.tanh(2 * np.arctanh(mid) - np.percentile(z, 97.5))
    assert basic_lo < boot.min() < lo


def test_the_bias_shifts_and_the_factor_widens_on_z():
    boot = _skewed_resamples()
    z = np.arctanh(boot)
    q_lo, mid, q_hi = np.percentile(z, [2.5, 50, 97.5])
    point, ref = 0.9, 0.93  # the resamples run high of the bootstrap world's value
    lo, hi = _interval(point, ref, boot, "corr", factor=1.2)
    centre = np.arctanh(point) - (mid - np.arctanh(ref))
    assert np.arctanh(lo) == pytest.approx(centre - 1.2 * (mid - q_lo), abs=1e-12)
    assert np.arctanh(hi) == pytest.approx(centre + 1.2 * (q_hi - mid), abs=1e-12)
    rmse = np.exp(np.random.default_rng(4).normal(np.log(6.0), 0.2, 1001))
    r_lo, r_hi = _interval(6.0, 6.0, rmse, "rmse")
    assert r_lo == pytest.approx(np.exp(np.log(6.0) - (np.median(np.log(rmse))
                                                       - np.percentile(np.log(rmse), 2.5))
                                        + np.log(6.0) - np.median(np.log(rmse))), rel=1e-12)
    assert r_lo < 6.0 < r_hi
