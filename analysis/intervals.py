"""DMOS confidence intervals from a bootstrap over raters.

DMOS(v) = Q(v) - Q(ref(v)) + ref_score. Its two terms are estimated from the same raters, so
their errors are correlated (a rater who is harsh on v is harsh on its reference too);
adding the two CIs in quadrature ignores that. Resampling whole raters keeps each rater's
ratings of v and of ref(v) together, so the interval carries the covariance.

Each resample recomputes the score model's estimator with the rater parameters of the full
fit held fixed (:class:`RaterWeights`): for ``mos``/``bt500`` the plain mean; for the MLE
models the bias-corrected, inconsistency-weighted mean that the MLE's alternating projection
converges to (Li & Bampis 2020), ``Q(e) = sum_s w_se (u_es - b_s) / sum_s w_se`` with
``w_se = 1 / (v_s^2 + a_c(e)^2)``. All resamples are one matrix product.

The half-width is ``t(0.975, n_eff - 1) * sqrt(n / (n - 1)) * sd_boot``: the bootstrap s.d.
of a mean over n resampled units is ``sqrt((n-1)/n)`` of the usual standard error, and with
20 raters a normal quantile would cover only about 93%; ``n`` counts the raters behind the
stimulus (and its reference), ``n_eff`` is Kish's effective number under the weights.
The coverage of these intervals is checked by simulation in ``benchmarks/bench_coverage.py``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import stats

from .data import RatingSet
from .errors import check_resamples

MIN_RATERS_FOR_INTERVAL = 3
"""Raters behind a DMOS (they rated the stimulus and its reference) below which the report
gives it no interval. Two raters give a bootstrap of three outcomes and a t quantile of 12.7:
an interval past both ends of the scale, or of zero width where the two agree, which reads
as certainty. The allocation still uses those widths: there they only rank stimuli."""


def reported_halfwidth(boot: RaterBootstrap, halfwidth: np.ndarray,
                       hidden: np.ndarray) -> np.ndarray:
    """``halfwidth`` with NaN for the conditions behind fewer than
    :data:`MIN_RATERS_FOR_INTERVAL` raters (hidden references keep their exact 0)."""
    few = ~np.asarray(hidden, dtype=bool) & (boot.n_raters < MIN_RATERS_FOR_INTERVAL)
    return np.where(few, np.nan, np.asarray(halfwidth, dtype=float))


@dataclass
class RaterWeights:
    """The full fit's rater parameters: bias (S,) and weight per stimulus and rater (E, S)."""

    bias: np.ndarray
    weight: np.ndarray


def estimator_weights(rs: RatingSet, res) -> RaterWeights:
    """Rater parameters of a fitted :class:`~analysis.scores.ScoreResult` on ``rs``."""
    n_stim, n_raters = rs.n_stimuli, rs.n_raters
    if res.model in ("mos", "bt500") or res.rater_inconsistency is None:
        return RaterWeights(np.zeros(n_raters), np.ones((n_stim, n_raters)))
    bias = np.nan_to_num(np.asarray(res.rater_bias, dtype=float))
    span = rs.scale_max - rs.scale_min
    # The MLE may drive a rater's inconsistency to 0; floor it so no rater gets all weight.
    v = np.maximum(np.nan_to_num(np.asarray(res.rater_inconsistency, dtype=float),
                                 nan=span), 0.02 * span)
    var = np.tile(v * v, (n_stim, 1))
    if res.content_ambiguity is not None and len(res.content):
        amb = dict(zip(res.content, np.nan_to_num(res.content_ambiguity), strict=True))
        a = np.array([amb.get(ref, 0.0) for ref in rs.stimuli["reference"]])
        var = var + (a * a)[:, None]
    return RaterWeights(bias, 1.0 / var)


def _cells(rs: RatingSet, w: RaterWeights) -> tuple[np.ndarray, np.ndarray]:
    """Per stimulus x rater: weighted bias-corrected vote sum and weighted vote count."""
    finite = np.isfinite(rs.scores)
    x = np.where(finite, rs.scores, 0.0)
    counts = finite.sum(axis=2).astype(float)
    sums = x.sum(axis=2) - counts * w.bias[None, :]
    return w.weight * sums, w.weight * counts


def quality_from_draws(num: np.ndarray, den: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Quality per stimulus for each rater multiset (rows of ``draws``: counts per rater)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return (num @ draws.T) / (den @ draws.T)


def dmos_from_quality_matrix(rs: RatingSet, q: np.ndarray) -> np.ndarray:
    """DMOS rows from quality rows (E, B): the P.910 difference against the hidden reference.

    A stimulus whose hidden reference was not rated has no DMOS (NaN) where others have one:
    its quality score in the same column would sit 100 - Q(ref) points off the rest. Where
    no hidden reference was rated at all (a design without them), every row keeps its
    quality score (the table and the report say so)."""
    ref = rs.reference_index()
    has = ref >= 0
    out = q.astype(float).copy()
    out[has] = q[has] - q[ref[has]] + rs.ref_score
    if has.any():
        out[~has] = np.nan
    return out


@dataclass
class RaterBootstrap:
    """DMOS of every stimulus under ``B`` resamples of the raters, plus the full panel's DMOS
    under the same estimator (the bootstrap world's truth)."""

    draws: np.ndarray  # (B, S) how often each rater is in each resample
    dmos: np.ndarray  # (E, B)
    dmos_full: np.ndarray  # (E,)
    n_raters: np.ndarray  # (E,) raters behind each DMOS
    n_eff: np.ndarray  # (E,) Kish effective number of raters

    def halfwidth(self) -> np.ndarray:
        """95% half-width per stimulus (see the module docstring)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            sd = np.nanstd(self.dmos, axis=1, ddof=1)
            n = self.n_raters.astype(float)
            inflate = np.sqrt(n / np.maximum(n - 1, 1))
            t = stats.t.ppf(0.975, np.maximum(self.n_eff - 1, 1))
            half = t * inflate * sd
        return np.where(n >= 2, half, np.nan)


def rater_bootstrap(rs: RatingSet, weights: RaterWeights, n_boot: int = 1000,
                    seed: int = 0) -> RaterBootstrap:
    """Resample raters with replacement ``n_boot`` times (seeded) and recompute DMOS."""
    n_boot = check_resamples(n_boot, "n_boot")
    rng = np.random.default_rng([seed, 11])
    n_raters = rs.n_raters
    picks = rng.integers(0, n_raters, size=(n_boot, n_raters))
    draws = np.zeros((n_boot, n_raters))
    np.add.at(draws, (np.repeat(np.arange(n_boot), n_raters), picks.ravel()), 1.0)
    num, den = _cells(rs, weights)
    q = quality_from_draws(num, den, draws)
    full = quality_from_draws(num, den, np.ones((1, n_raters)))[:, 0]
    # Raters behind each DMOS: rated the stimulus and (for conditions) its hidden reference.
    rated = np.isfinite(rs.scores).any(axis=2)
    ref = rs.reference_index()
    behind = rated.copy()
    has = (ref >= 0) & ~rs.hidden_reference_mask
    behind[has] &= rated[ref[has]]
    wts = np.where(behind, weights.weight, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        n_eff = wts.sum(axis=1) ** 2 / (wts * wts).sum(axis=1)
    return RaterBootstrap(draws, dmos_from_quality_matrix(rs, q),
                          dmos_from_quality_matrix(rs, full[:, None])[:, 0],
                          behind.sum(axis=1), np.nan_to_num(n_eff))
