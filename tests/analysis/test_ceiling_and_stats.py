"""Vectorised statistics against scipy; human ceiling and CI curve on generated panels."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from analysis.ceiling import ci_width_curve, split_half
from analysis.errors import AnalysisError
from analysis.inputs import ratings_from_frame
from analysis.intervals import estimator_weights, rater_bootstrap
from analysis.scores import fit_scores
from analysis.stats import (
    kendall_columns,
    pearson_columns,
    percentile_interval,
    rmse_columns,
    spearman_columns,
)
from analysis.synthetic import synthetic_study


def test_column_statistics_match_scipy() -> None:
    rng = np.random.default_rng(1)
    x = rng.integers(0, 8, size=(40, 6)).astype(float)  # many ties
    y = x + rng.normal(0, 2, size=x.shape)
    y[:, 0] = np.round(y[:, 0])
    p, s, k, r = (pearson_columns(x, y), spearman_columns(x, y), kendall_columns(x, y),
                  rmse_columns(x, y))
    for j in range(6):
        assert p[j] == pytest.approx(stats.pearsonr(x[:, j], y[:, j])[0], abs=1e-12)
        assert s[j] == pytest.approx(stats.spearmanr(x[:, j], y[:, j])[0], abs=1e-12)
        assert k[j] == pytest.approx(stats.kendalltau(x[:, j], y[:, j])[0], abs=1e-12)
        assert r[j] == pytest.approx(np.sqrt(np.mean((x[:, j] - y[:, j]) ** 2)), abs=1e-12)


def test_percentile_interval() -> None:
    lo, hi = percentile_interval(np.arange(1001.0))
    assert (lo, hi) == pytest.approx((25.0, 975.0))


def _panel(noise: float, bias: float = 0.0, seed: int = 4):
    st = synthetic_study(n_scenes=6, methods=("blur", "noise"), levels=3, n_raters=12,
                         noise_sd=noise, bias_sd=bias, seed=seed)
    return ratings_from_frame(st.ratings, st.manifest)


@pytest.mark.parametrize("count", [0, -3, 100_001, 10**11])
def test_resample_counts_out_of_range_are_refused_before_allocating(count: int) -> None:
    """10**11 split-halves used to die with MemoryError (a traceback); any count outside
    1..100000 is a one-line AnalysisError naming the argument, before any array is made."""
    rs = _panel(1.0)
    with pytest.raises(AnalysisError, match=r"n_splits must be a whole number from 1 to "
                                            rf"100000, got {count}$"):
        split_half(rs, n_splits=count, seed=0)
    weights = estimator_weights(rs, fit_scores(rs, "mos", n_boot=5))
    with pytest.raises(AnalysisError, match=r"n_boot must be a whole number from 1 to 100000"):
        rater_bootstrap(rs, weights, count, seed=0)


def test_ceiling_is_one_for_noiseless_raters() -> None:
    # Rater biases cancel in the DMOS difference, so biased but noiseless halves agree exactly.
    sh = split_half(_panel(0.0, bias=5.0), n_splits=200, seed=0)
    assert np.allclose(sh.values["plcc"], 1.0)
    assert np.allclose(sh.values["srcc"], 1.0)
    assert np.allclose(sh.values["rmse"], 0.0, atol=1e-9)


def test_ceiling_falls_with_noise() -> None:
    medians = [split_half(_panel(n), n_splits=300, seed=0).summary()["plcc"]["median"]
               for n in (3.0, 12.0, 30.0)]
    assert medians[0] > medians[1] > medians[2]
    assert medians[0] > 0.97


def test_split_half_is_seeded() -> None:
    rs = _panel(8.0)
    a = split_half(rs, n_splits=50, seed=3).values["plcc"]
    b = split_half(rs, n_splits=50, seed=3).values["plcc"]
    c = split_half(rs, n_splits=50, seed=4).values["plcc"]
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_split_half_matches_direct_computation() -> None:
    """One split recomputed by hand with pandas-free numpy means."""
    rs = _panel(8.0)
    sh = split_half(rs, n_splits=1, seed=9)
    rng = np.random.default_rng(9)
    order = np.argsort(rng.random((1, rs.n_raters)), axis=1)[0]
    half = rs.n_raters // 2
    ref = rs.reference_index()
    cond = ~rs.hidden_reference_mask

    def dmos(raters):
        mos = np.nanmean(rs.scores[:, raters, :].reshape(rs.n_stimuli, -1), axis=1)
        return (mos - mos[ref] + 100.0)[cond]

    a, b = dmos(order[:half]), dmos(order[half:])
    assert sh.values["plcc"][0] == pytest.approx(stats.pearsonr(a, b)[0], abs=1e-12)
    assert sh.values["krcc"][0] == pytest.approx(stats.kendalltau(a, b)[0], abs=1e-12)


def test_ci_width_curve_power_law() -> None:
    curve = ci_width_curve(_panel(10.0), draws=40, seed=0)
    # from 3 raters, as every interval of the report (two raters' t quantile is 12.7)
    assert list(curve.n_raters) == list(range(3, 13))
    assert (np.diff(curve.mean_width) < 0).all()
    # Homogeneous raters: width ~ t(n) / sqrt(n), a decay a little faster than n^-0.5.
    assert 0.4 < curve.b < 1.0
    fitted = curve.a * curve.n_raters ** (-curve.b)
    big = curve.n_raters >= 5  # the range the power law is fitted on
    assert np.max(np.abs(fitted - curve.mean_width)[big] / curve.mean_width[big]) < 0.05
    red = curve.reduction_per_rater()
    assert red[5] > red[12] > 0
