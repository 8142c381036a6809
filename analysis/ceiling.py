"""The human ceiling: how well one half of the panel predicts the other half.

Raters are split at random into two halves many times (seeded); each half's DMOS (plain
means, P.910 differencing against the hidden reference) is computed for all splits at once
with matrix products, then PLCC/SRCC/KRCC/RMSE between halves over the distorted stimuli.
A split-half r underestimates the full panel's reliability; the Spearman-Brown corrected
PLCC is reported beside it. The CI-width curve subsamples n raters (seeded) and fits a power
law width(n) = a * n^(-b) (from 5 raters on, when there are enough points).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import optimize, stats

from .data import RatingSet
from .errors import AnalysisError
from .stats import all_columns, percentile_interval

log = logging.getLogger(__name__)


@dataclass
class SplitHalf:
    """Distribution of half-versus-half agreement over random splits."""

    n_splits: int
    values: dict[str, np.ndarray]

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for key, v in self.values.items():
            lo, hi = percentile_interval(v)
            out[key] = {"median": float(np.nanmedian(v)), "mean": float(np.nanmean(v)),
                        "ci95_low": lo, "ci95_high": hi}
        r = float(np.nanmedian(self.values["plcc"]))
        out["plcc_spearman_brown"] = {"median": 2 * r / (1 + r) if r > -1 else float("nan")}
        return out


def _sums(rs: RatingSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per stimulus x rater: sum of votes, sum of squares, vote count."""
    finite = np.isfinite(rs.scores)
    x = np.where(finite, rs.scores, 0.0)
    return x.sum(axis=2), (x * x).sum(axis=2), finite.sum(axis=2).astype(float)


def _dmos_from_sums(rs: RatingSet, s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """DMOS (E, B) from per-split sums and counts (E, B)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        mos = s / c
    ref = rs.reference_index()
    has = ref >= 0
    out = mos.copy()
    out[has] = mos[has] - mos[ref[has]] + rs.ref_score
    return out


def split_half(rs: RatingSet, n_splits: int = 1000, seed: int = 0) -> SplitHalf:
    """Human ceiling by ``n_splits`` random half splits of the raters (vectorised)."""
    if rs.n_raters < 4:
        raise AnalysisError(f"split-half ceiling needs at least 4 raters, have {rs.n_raters}")
    rng = np.random.default_rng(seed)
    n = rs.n_raters
    half = n // 2
    order = np.argsort(rng.random((n_splits, n)), axis=1)
    mask = np.zeros((n_splits, n))
    np.put_along_axis(mask, order[:, :half], 1.0, axis=1)
    other = np.zeros((n_splits, n))
    np.put_along_axis(other, order[:, half: 2 * half], 1.0, axis=1)  # odd n: one rater rests
    sums, _, counts = _sums(rs)
    da = _dmos_from_sums(rs, sums @ mask.T, counts @ mask.T)
    db = _dmos_from_sums(rs, sums @ other.T, counts @ other.T)
    rows = ~rs.hidden_reference_mask
    da, db = da[rows], db[rows]
    # Stimuli that some split leaves unrated in one half (sparse designs) are left out.
    ok = np.isfinite(da).all(axis=1) & np.isfinite(db).all(axis=1)
    if ok.sum() < 3:
        raise AnalysisError("too few stimuli rated by both halves of the panel for a "
                            "split-half ceiling")
    return SplitHalf(n_splits, all_columns(da[ok], db[ok]))


@dataclass
class CiCurve:
    """Mean DMOS 95% CI width against the number of raters, with a power-law fit."""

    n_raters: np.ndarray
    mean_width: np.ndarray
    a: float
    b: float

    def reduction_per_rater(self) -> dict[int, float]:
        """Mean CI reduction gained by adding the n-th rater (from the measured curve)."""
        return {int(n): float(w0 - w1) for n, w0, w1 in
                zip(self.n_raters[1:], self.mean_width[:-1], self.mean_width[1:], strict=True)}


def ci_width_curve(rs: RatingSet, draws: int = 100, seed: int = 0) -> CiCurve:
    """Mean t-based 95% CI width of MOS over stimuli for random panels of n = 2..S raters."""
    rng = np.random.default_rng(seed)
    sums, sq, counts = _sums(rs)
    ns, widths = [], []
    for k in range(2, rs.n_raters + 1):
        order = np.argsort(rng.random((draws, rs.n_raters)), axis=1)[:, :k]
        mask = np.zeros((draws, rs.n_raters))
        np.put_along_axis(mask, order, 1.0, axis=1)
        s, q, c = sums @ mask.T, sq @ mask.T, counts @ mask.T
        with np.errstate(invalid="ignore", divide="ignore"):
            var = (q - s * s / c) / (c - 1)
            width = 2 * stats.t.ppf(0.975, np.maximum(c - 1, 1)) * np.sqrt(
                np.maximum(var, 0) / c)
        width = np.where(c > 1, width, np.nan)
        ns.append(k)
        widths.append(float(np.nanmean(width)))
    n, w = np.array(ns, dtype=float), np.array(widths)
    good = np.isfinite(w) & (w > 0)
    # Very small panels have few degrees of freedom and t-quantiles that dominate the fit;
    # fit from 5 raters on when the curve is long enough (the paper reports from the 5th).
    if (good & (n >= 5)).sum() >= 3:
        good &= n >= 5
    if good.sum() >= 2:
        slope, intercept = np.polyfit(np.log(n[good]), np.log(w[good]), 1)
        try:
            (a, b), _ = optimize.curve_fit(lambda x, a, b: a * x ** (-b), n[good], w[good],
                                           p0=(np.exp(intercept), -slope), maxfev=10000)
        except (RuntimeError, optimize.OptimizeWarning):
            a, b = np.exp(intercept), -slope
    else:
        a = b = float("nan")
    return CiCurve(n, w, float(a), float(b))
