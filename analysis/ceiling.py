"""The human ceiling: how well one half of the panel predicts the other half.

Raters are split at random into two halves many times (seeded); each half's DMOS (plain
means, P.910 differencing against the hidden reference) is computed for all splits at once
with matrix products, then PLCC/SRCC/KRCC/RMSE between halves over the distorted stimuli.
A split-half r underestimates the full panel's reliability; the Spearman-Brown corrected
PLCC (projected to all n raters, also when n is odd and one rater rests in each split) is
reported beside it, and its square root: the PLCC a predictor of the true quality would reach
against the full panel's DMOS, the ceiling for a metric. The CI-width curve subsamples n
raters (seeded), from the 3 raters the report's intervals need on, and fits a power law
width(n) = a * n^(-b) (from 5 raters on, when there are enough points).
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import optimize, stats

from .data import RatingSet
from .errors import AnalysisError, check_resamples
from .intervals import MIN_RATERS_FOR_INTERVAL
from .stats import all_columns_masked, percentile_interval

log = logging.getLogger(__name__)


@dataclass
class SplitHalf:
    """Distribution of half-versus-half agreement over random splits."""

    n_splits: int
    values: dict[str, np.ndarray]
    n_stimuli: int = 0  # distorted stimuli in the rating set
    median_used: float = float("nan")  # stimuli a split could use (both halves rated them)
    n_raters: int = 0  # the panel split (0: unknown, then taken as twice a half)

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for key, v in self.values.items():
            lo, hi = percentile_interval(v)
            # the spread of the splits (percentiles), not a confidence interval: hence the names
            out[key] = {"median": float(np.nanmedian(v)), "mean": float(np.nanmean(v)),
                        "p2_5": lo, "p97_5": hi}
        r = float(np.nanmedian(self.values["plcc"]))
        sb = spearman_brown(r, self.n_raters)
        out["plcc_spearman_brown"] = {"median": sb}
        # classical test theory: a predictor of the true score correlates with a mean of
        # reliability rho at sqrt(rho); the ceiling a metric faces against the full panel
        out["plcc_full_panel_bound"] = {"median": math.sqrt(sb) if sb >= 0 else float("nan")}
        return out


def spearman_brown(r: float, n_raters: int) -> float:
    """The split-half r projected to the whole panel of ``n_raters``: each half holds
    floor(n/2) raters (an odd panel rests one in every split), so the panel is
    k = n / floor(n/2) halves long and r_n = k r / (1 + (k - 1) r) (k = 2 for even n)."""
    if not r > -1:
        return float("nan")
    k = n_raters / (n_raters // 2) if n_raters >= 2 else 2.0
    return k * r / (1 + (k - 1) * r)


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
    n_splits = check_resamples(n_splits, "n_splits")
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
    # Unbalanced designs: each split uses the stimuli both of its halves rated.
    values, used = all_columns_masked(da, db)
    if not np.isfinite(values["plcc"]).any():
        raise AnalysisError("too few stimuli rated by both halves of the panel for a "
                            "split-half ceiling")
    return SplitHalf(n_splits, values, int(rows.sum()), float(np.median(used)), n)


@dataclass
class CiCurve:
    """DMOS 95% CI width against the number of raters, in two readings.

    ``mean_width``: mean t-based 95% CI width of the per-stimulus mean score (MOS) for random
    panels of n raters, with a power-law fit ``width = a n^-b`` (``b`` near 0.5 for
    independent raters; larger at small n, where Student's t quantiles shrink fast).

    ``dmos_width``: the CGVQM+D paper's curve, the average width of the DMOS 95% CI (P.910
    per-rater differences against the hidden reference, Student t over raters) for n
    participants; ``reduction[n] = dmos_width[n-1] - dmos_width[n]`` is the CI reduction
    bought by the n-th participant. Its decay is fitted from the 5th participant on as an
    exponential ``c exp(-rate n)`` and as a power law ``c n^-power``; the paper's figures
    (reduction 1.83 at the 5th, 0.12 at the 20th, "decay rate 0.19") describe this reduction,
    and 1.83 exp(-0.19 x 15) = 0.11 matches the exponential reading. ``b`` above and ``rate``
    here measure different things and are not comparable.
    """

    n_raters: np.ndarray
    mean_width: np.ndarray
    a: float
    b: float
    dmos_width: np.ndarray | None = None
    decay_rate: float = float("nan")
    decay_scale: float = float("nan")
    reduction_power: float = float("nan")
    decay_from: int = 0
    """The first participant whose reduction the decay fit used (5, or 3 in short curves)."""

    def reduction_per_rater(self) -> dict[int, float]:
        """Mean DMOS CI reduction gained by adding the n-th rater (the paper's reading;
        the MOS curve when no DMOS curve could be computed)."""
        w = self.dmos_width if self.dmos_width is not None else self.mean_width
        return {int(n): float(w0 - w1) for n, w0, w1 in
                zip(self.n_raters[1:], w[:-1], w[1:], strict=True)}


def _t_widths(sums: np.ndarray, sq: np.ndarray, counts: np.ndarray,
              mask: np.ndarray) -> np.ndarray:
    """Mean t-based 95% CI width over stimuli, for each rater mask (rows)."""
    s, q, c = sums @ mask.T, sq @ mask.T, counts @ mask.T
    with np.errstate(invalid="ignore", divide="ignore"):
        var = (q - s * s / c) / (c - 1)
        width = 2 * stats.t.ppf(0.975, np.maximum(c - 1, 1)) * np.sqrt(np.maximum(var, 0) / c)
    width = np.where(c > 1, width, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(width)


def per_rater_dmos(rs: RatingSet) -> np.ndarray | None:
    """P.910 per-rater DMOS ``mean_r u(v) - mean_r u(ref(v)) + ref_score`` (conditions x
    raters, NaN where the rater lacks either); None when no condition has a hidden reference."""
    means = rs.rater_means()
    ref = rs.reference_index()
    rows = (ref >= 0) & ~rs.hidden_reference_mask
    if not rows.any():
        return None
    return means[rows] - means[ref[rows]] + rs.ref_score


def _power_fit(n: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    good = np.isfinite(w) & (w > 0)
    if good.sum() < 2:
        return float("nan"), float("nan")
    slope, intercept = np.polyfit(np.log(n[good]), np.log(w[good]), 1)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            (a, b), _ = optimize.curve_fit(lambda x, a, b: a * x ** (-b), n[good], w[good],
                                           p0=(np.exp(intercept), -slope), maxfev=10000)
    except (RuntimeError, ValueError, optimize.OptimizeWarning):
        a, b = np.exp(intercept), -slope
    return float(a), float(b)


def ci_width_curve(rs: RatingSet, draws: int = 100, seed: int = 0) -> CiCurve:
    """CI width against panel size for random panels of n = 3..S raters (seeded). Two raters
    are left out as everywhere in the report (:data:`MIN_RATERS_FOR_INTERVAL`): their t
    quantile of 12.7 would make the width at n = 2, and the 3rd rater's "reduction", mostly
    the quantile's."""
    rng = np.random.default_rng(seed)
    sums, sq, counts = _sums(rs)
    d = per_rater_dmos(rs)
    if d is not None:
        fin = np.isfinite(d)
        dx = np.where(fin, d, 0.0)
        dsum, dsq, dcount = dx, dx * dx, fin.astype(float)
    ns, widths, dwidths = [], [], []
    for k in range(MIN_RATERS_FOR_INTERVAL, rs.n_raters + 1):
        order = np.argsort(rng.random((draws, rs.n_raters)), axis=1)[:, :k]
        mask = np.zeros((draws, rs.n_raters))
        np.put_along_axis(mask, order, 1.0, axis=1)
        ns.append(k)
        widths.append(float(_t_widths(sums, sq, counts, mask)))
        if d is not None:
            dwidths.append(float(_t_widths(dsum, dsq, dcount, mask)))
    n, w = np.array(ns, dtype=float), np.array(widths)
    # Very small panels have few degrees of freedom and t-quantiles that dominate the fit;
    # fit from 5 raters on when the curve is long enough (the paper reports from the 5th).
    from_five = n >= 5 if (np.isfinite(w) & (n >= 5)).sum() >= 3 else np.ones_like(n, bool)
    a, b = _power_fit(n[from_five], w[from_five])
    curve = CiCurve(n, w, a, b)
    if d is not None:
        dw = np.array(dwidths)
        curve.dmos_width = dw
        red_n, red = n[1:], dw[:-1] - dw[1:]
        use = (red_n >= 5) & np.isfinite(red) & (red > 0)
        if use.sum() < 3:
            use = np.isfinite(red) & (red > 0)
        if use.sum() >= 2:
            curve.decay_from = int(red_n[use].min())
            slope, intercept = np.polyfit(red_n[use], np.log(red[use]), 1)
            curve.decay_rate, curve.decay_scale = float(-slope), float(np.exp(intercept))
            curve.reduction_power = _power_fit(red_n[use], red[use])[1]
    return curve
