"""ITU-T P.1401 statistics and the tests of dependent correlations, against published worked
examples, hand-worked definitions, and their null distributions by simulation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from analysis.p1401 import (
    dependent_correlation_tests,
    outlier_ratio,
    rmse_dof,
    rmse_f_test,
    rmse_star,
    steiger_z,
    williams_t,
)


def test_williams_t_howell_worked_example() -> None:
    """Howell, Statistical Methods for Psychology (6th ed., p. 262; also reproduced in
    B. Weaver's Williams1959.sps): r12 = .80, r13 = .72, r23 = .89, N = 26 gives
    t = 1.361 on 23 df, two-tailed p = .187."""
    t, df = williams_t(0.80, 0.72, 0.89, 26)
    assert df == 23
    assert t == pytest.approx(1.361, abs=5e-4)
    assert 2 * stats.t.sf(t, df) == pytest.approx(0.187, abs=5e-4)


def test_williams_t_steiger_case_a() -> None:
    """Steiger (1980) case A as used in the psych package's r.test example
    (n = 103, r12 = .4, r13 = .5, r23 = .1): t = -0.89, two-tailed p = 0.37."""
    t, df = williams_t(0.4, 0.5, 0.1, 103)
    assert round(t, 2) == -0.89
    assert round(2 * stats.t.sf(abs(t), df), 2) == 0.37


def _simulated_r(rho12: float, rho13: float, rho23: float, n: int, reps: int,
                 seed: int) -> tuple[np.ndarray, ...]:
    cov = np.array([[1, rho12, rho13], [rho12, 1, rho23], [rho13, rho23, 1]])
    x = np.random.default_rng(seed).multivariate_normal(np.zeros(3), cov, size=(reps, n))
    x -= x.mean(axis=1, keepdims=True)
    c = np.einsum("rni,rnj->rij", x, x)
    d = np.sqrt(np.einsum("rii->ri", c))
    r = c / d[:, :, None] / d[:, None, :]
    return r[:, 0, 1], r[:, 0, 2], r[:, 1, 2]


def test_dependent_correlation_tests_hold_their_level_under_the_null() -> None:
    """Under H0 (rho12 = rho13) Williams' t follows t(n-3) and Steiger's Z the standard
    normal: each rejects about 5% at the two-sided 0.05 level (4000 simulated samples)."""
    r12, r13, r23 = _simulated_r(0.6, 0.6, 0.5, 60, 4000, seed=0)
    t = np.array([williams_t(a, b, c, 60)[0] for a, b, c in zip(r12, r13, r23, strict=True)])
    z = np.array([steiger_z(a, b, c, 60) for a, b, c in zip(r12, r13, r23, strict=True)])
    se = np.sqrt(0.05 * 0.95 / 4000)
    assert np.mean(np.abs(t) > stats.t.ppf(0.975, 57)) == pytest.approx(0.05, abs=3 * se)
    assert np.mean(np.abs(z) > 1.959964) == pytest.approx(0.05, abs=3 * se)
    assert np.std(z) == pytest.approx(1.0, abs=0.05)


def test_steiger_variance_matches_the_simulated_variance_of_z12_minus_z13() -> None:
    """Steiger's Z divides z12 - z13 by its asymptotic s.d. sqrt((2 - 2 s) / (n - 3));
    the simulated s.d. of z12 - z13 must match (independent of the formula)."""
    r12, r13, r23 = _simulated_r(0.7, 0.7, 0.3, 200, 4000, seed=1)
    diff = np.arctanh(r12) - np.arctanh(r13)
    z = np.array([steiger_z(a, b, c, 200) for a, b, c in zip(r12, r13, r23, strict=True)])
    implied_sd = diff / z
    assert np.std(diff) == pytest.approx(np.median(implied_sd), rel=0.05)


def test_tests_have_power_and_direction() -> None:
    rng = np.random.default_rng(3)
    y = rng.normal(0, 1, 200)
    a = y + rng.normal(0, 0.5, 200)
    b = y + rng.normal(0, 1.5, 200)
    res = dependent_correlation_tests(y, a, b)
    assert res["williams_t"] > 3 and res["williams_p"] < 1e-3 and res["steiger_p"] < 1e-3
    flipped = dependent_correlation_tests(y, b, a)
    assert flipped["williams_p"] > 0.999


def test_rmse_and_rmse_star_by_the_p1401_definitions() -> None:
    """Hand-worked: errors 0.5, -1.0, 2.0, 0.0, -0.3, 1.2 with ci95 0.4, 0.4, 1.0, 0.2, 0.5,
    1.5 and d = 4 (P.1401's third-order mapping): rmse = sqrt(6.78 / 2) = 1.8412,
    Perror* = 0.1, 0.6, 1.0, 0, 0, 0 -> rmse* = sqrt(1.37 / 2) = 0.8276; outliers (error
    beyond its ci95): 3 of 6."""
    y = np.array([3.0, 2.0, 4.0, 1.5, 2.2, 3.3])
    err = np.array([0.5, -1.0, 2.0, 0.0, -0.3, 1.2])
    ci = np.array([0.4, 0.4, 1.0, 0.2, 0.5, 1.5])
    pred = y - err
    assert rmse_dof(y, pred, 4) == pytest.approx(np.sqrt(6.78 / 2))
    assert rmse_star(y, pred, ci, 4) == pytest.approx(np.sqrt(1.37 / 2))
    assert outlier_ratio(y, pred, ci) == pytest.approx(0.5)
    assert rmse_star(y, pred, np.zeros(6), 4) == pytest.approx(rmse_dof(y, pred, 4))
    assert np.isnan(rmse_dof(y[:4], pred[:4], 4))  # N - d must be positive


def test_stimuli_without_an_interval_are_left_out_of_both_ci_statistics() -> None:
    """A stimulus rated by one rater has no DMOS CI. It used to count as inside its CI for
    the outlier ratio and to make rmse* NaN. Both now use the stimuli that have a CI: here
    the five of the example above without the third (error 2.0): Perror* = 0.1, 0.6, 0, 0, 0,
    so rmse* = sqrt(0.37 / (5 - 2)), outliers 2 of 5."""
    y = np.array([3.0, 2.0, 4.0, 1.5, 2.2, 3.3])
    err = np.array([0.5, -1.0, 2.0, 0.0, -0.3, 1.2])
    ci = np.array([0.4, 0.4, np.nan, 0.2, 0.5, 1.5])
    pred = y - err
    assert rmse_star(y, pred, ci, 2) == pytest.approx(np.sqrt(0.37 / 3))
    assert outlier_ratio(y, pred, ci) == pytest.approx(2 / 5)
    assert np.isnan(outlier_ratio(y, pred, np.full(6, np.nan)))


def test_rmse_f_test_matches_scipy() -> None:
    f, p = rmse_f_test(0.6, 80, 5, 0.5, 80, 5)
    assert f == pytest.approx(1.44)
    assert p == pytest.approx(stats.f.sf(1.44, 75, 75))
    assert p < 0.06  # a 20% larger rmse on 80 stimuli is borderline
