"""Metric-versus-subjective statistics of ITU-T P.1401 and tests of dependent correlations.

- :func:`rmse_dof`: P.1401's prediction error ``sqrt(sum(Perror^2) / (N - d))``, ``d`` the
  number of parameters of the mapping (5 for the 5-parameter logistic, 2 for a line);
- :func:`rmse_star`: the epsilon-insensitive rmse*, errors shrunk by each stimulus's 95% CI
  (``max(0, |Perror| - ci95)``) with the same ``N - d``: only error beyond the subjective
  uncertainty counts;
- :func:`outlier_ratio`: share of stimuli whose error exceeds their 95% CI;
- :func:`rmse_f_test`: P.1401's F-test of two rmse values (ratio of squares, ``N - d``
  degrees of freedom each), also used for rmse*;
- :func:`williams_t` (Williams 1959, recommended by Steiger 1980) and :func:`steiger_z`
  (Steiger 1980, Z1* with the pooled r): is r(y, a) larger than r(y, b) when both use the
  same stimuli? Both need r(a, b), the correlation of the two metrics' predictions.
"""

from __future__ import annotations

import numpy as np
from scipy import stats


def rmse_dof(y: np.ndarray, pred: np.ndarray, d: int) -> float:
    """P.1401 rmse with the degrees-of-freedom correction ``N - d``."""
    e = np.asarray(y, dtype=float) - np.asarray(pred, dtype=float)
    n = e.size
    if n - d <= 0:
        return float("nan")
    return float(np.sqrt((e * e).sum() / (n - d)))


def _with_interval(y: np.ndarray, pred: np.ndarray, ci95: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """|y - pred| and the CI half-width of the stimuli that have one: a stimulus behind which
    fewer than three raters stand has no interval (``MIN_RATERS_FOR_INTERVAL``), so it can
    be neither inside nor outside it."""
    e = np.abs(np.asarray(y, dtype=float) - np.asarray(pred, dtype=float))
    ci = np.asarray(ci95, dtype=float)
    has = np.isfinite(ci)
    return e[has], ci[has]


def rmse_star(y: np.ndarray, pred: np.ndarray, ci95: np.ndarray, d: int) -> float:
    """P.1401 epsilon-insensitive rmse*: ``sqrt(sum(max(0, |y - pred| - ci95)^2) / (N - d))``
    over the N stimuli that have a CI."""
    e, ci = _with_interval(y, pred, ci95)
    e = np.maximum(0.0, e - ci)
    n = e.size
    if n - d <= 0:
        return float("nan")
    return float(np.sqrt((e * e).sum() / (n - d)))


def outlier_ratio(y: np.ndarray, pred: np.ndarray, ci95: np.ndarray) -> float:
    """Share of the stimuli with a CI whose prediction error is larger than its half-width."""
    e, ci = _with_interval(y, pred, ci95)
    return float(np.mean(e > ci)) if e.size else float("nan")


def rmse_f_test(rmse_a: float, n_a: int, d_a: int, rmse_b: float, n_b: int,
                d_b: int) -> tuple[float, float]:
    """F = rmse_a^2 / rmse_b^2 and the one-tailed p-value that ``a``'s error is larger
    (P.1401: significant when F exceeds F(0.95; N_a - d_a, N_b - d_b))."""
    df_a, df_b = n_a - d_a, n_b - d_b
    if df_a <= 0 or df_b <= 0 or not rmse_b > 0:
        return float("nan"), float("nan")
    f = (rmse_a / rmse_b) ** 2
    return float(f), float(stats.f.sf(f, df_a, df_b))


def williams_t(r12: float, r13: float, r23: float, n: int) -> tuple[float, int]:
    """Williams' t for H0: rho12 = rho13 (variable 1 shared), with n - 3 degrees of freedom.

    t = (r12 - r13) sqrt((n - 1)(1 + r23) / (2 (n - 1)/(n - 3) |R| + rbar^2 (1 - r23)^3)),
    |R| = 1 - r12^2 - r13^2 - r23^2 + 2 r12 r13 r23, rbar = (r12 + r13) / 2.
    """
    if n <= 3:
        return float("nan"), n - 3
    det = 1 - r12 * r12 - r13 * r13 - r23 * r23 + 2 * r12 * r13 * r23
    rbar = (r12 + r13) / 2
    den = 2 * (n - 1) / (n - 3) * det + rbar * rbar * (1 - r23) ** 3
    if not den > 0:
        return float("nan"), n - 3
    return float((r12 - r13) * np.sqrt((n - 1) * (1 + r23) / den)), n - 3


def steiger_z(r12: float, r13: float, r23: float, n: int) -> float:
    """Steiger's (1980) Z1* for H0: rho12 = rho13 with the pooled r (his equations 3, 10, 14).

    Z = (z12 - z13) sqrt(n - 3) / sqrt(2 - 2 s), s = psi / (1 - rbar^2)^2,
    psi = r23 (1 - 2 rbar^2) - rbar^2 (1 - 2 rbar^2 - r23^2) / 2, z = atanh(r).
    """
    rbar = (r12 + r13) / 2
    if n <= 3 or not max(abs(r12), abs(r13)) < 1:
        return float("nan")
    psi = r23 * (1 - 2 * rbar * rbar) - 0.5 * rbar * rbar * (1 - 2 * rbar * rbar - r23 * r23)
    s = psi / (1 - rbar * rbar) ** 2
    if not (2 - 2 * s) > 0:
        return float("nan")
    return float((np.arctanh(r12) - np.arctanh(r13)) * np.sqrt(n - 3) / np.sqrt(2 - 2 * s))


def dependent_correlation_tests(y: np.ndarray, pred_a: np.ndarray,
                                pred_b: np.ndarray) -> dict[str, float]:
    """One-tailed tests that PLCC(y, a) > PLCC(y, b) on the same stimuli."""
    n = len(y)
    with np.errstate(invalid="ignore", divide="ignore"):
        r12 = float(np.corrcoef(y, pred_a)[0, 1])
        r13 = float(np.corrcoef(y, pred_b)[0, 1])
        r23 = float(np.corrcoef(pred_a, pred_b)[0, 1])
    t, df = williams_t(r12, r13, r23, n)
    z = steiger_z(r12, r13, r23, n)
    return {
        "r_ab": r23,
        "williams_t": t,
        "williams_p": float(stats.t.sf(t, df)) if np.isfinite(t) else float("nan"),
        "steiger_z": z,
        "steiger_p": float(stats.norm.sf(z)) if np.isfinite(z) else float("nan"),
    }
