"""Adaptive allocation of ratings: which stimuli the next block of trials should hold.

The study server calls this between participants (and at their breaks) with every rating
that has arrived. The DMOS intervals come from the analysis' own model (:func:`fit_scores`:
SUREAL's MLE and the rater bootstrap), so the allocation chases exactly the widths the
report will show.

**Forecast.** A condition's DMOS is ``Q(v) - Q(ref) + 100``; its variance has a part from
its own ratings and a part from its reference's, each shrinking like one over the number of
ratings (:func:`forecast_halfwidth`). The variance of one rating comes from the fitted model
(quality, rater bias and inconsistency, content ambiguity, clipping at the scale's ends:
:func:`rating_variance`), with ``n`` counting the ratings already in and those planned in
blocks issued but not yet returned.

**Plan.** Greedily, one trial at a time, the block takes the stimulus whose extra rating
lowers ``sum(h ** power)`` over the conditions' forecast half-widths ``h`` most: with the
default ``power`` of 16 that is close to minimising the widest interval, and a reference is
chosen when the conditions that depend on it gain more together. No stimulus appears more
than ``max_per_block`` times in a block. Everything is deterministic: ties go to the first
stimulus in manifest order, and the trial order is drawn from the block's seed elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .data import RatingSet
from .errors import AnalysisError
from .scores import ScoreResult, fit_scores

POWER = 16.0
MAX_PER_BLOCK = 3
GAUSS_HERMITE_NODES = 40


@dataclass(frozen=True)
class AllocationFit:
    """What a block plan needs from a fit, per stimulus in manifest order."""

    stimulus_ids: list[str]
    halfwidth: np.ndarray  # (E,) DMOS 95 % half-width now; 0 for hidden references
    own_share: np.ndarray  # (E,) share of a condition's variance from its own ratings
    reference: np.ndarray  # (E,) row of the stimulus's hidden reference, -1 for none
    hidden: np.ndarray  # (E,) bool
    ratings: np.ndarray  # (E,) ratings the fit used

    def condition_mask(self) -> np.ndarray:
        return ~self.hidden & (self.reference >= 0)


def rating_variance(rs: RatingSet, res: ScoreResult) -> np.ndarray:
    """Per stimulus: the variance of one bias-corrected rating that the fitted model
    predicts, ``Var[clip(Q + b_s + sqrt(v_s^2 + a_c^2) e, scale)]`` averaged over the panel's
    raters (Gauss-Hermite quadrature). It comes from the fitted quality, rater and content
    parameters, not from each stimulus's own scatter, so the plan does not chase the noise
    of the intervals it is trying to narrow (which would leave intervals that came out too
    narrow by chance under-sampled, and under-covering)."""
    z, w = np.polynomial.hermite_e.hermegauss(GAUSS_HERMITE_NODES)
    w = w / w.sum()
    q = np.asarray(res.quality, dtype=float)
    bias = np.nan_to_num(np.asarray(res.rater_bias if res.rater_bias is not None
                                    else np.zeros(rs.n_raters), dtype=float))
    incons = np.nan_to_num(np.asarray(res.rater_inconsistency if res.rater_inconsistency
                                      is not None else np.zeros(rs.n_raters), dtype=float))
    if res.content_ambiguity is not None and len(res.content):
        by_content = dict(zip(res.content, np.nan_to_num(res.content_ambiguity), strict=True))
        amb = np.array([by_content.get(r, 0.0) for r in rs.stimuli["reference"]])
    else:
        amb = content_ambiguity_from_residuals(rs, q, bias, incons)
    sd = np.sqrt(incons[None, :, None] ** 2 + amb[:, None, None] ** 2)
    y = np.clip(q[:, None, None] + bias[None, :, None] + sd * z[None, None, :],
                rs.scale_min, rs.scale_max)
    m1 = (y * w).sum(axis=2)
    var = ((y * y * w).sum(axis=2) - m1 * m1).mean(axis=1)
    floor = (0.01 * (rs.scale_max - rs.scale_min)) ** 2  # a stimulus pinned at an end
    return np.maximum(var, floor)


def content_ambiguity_from_residuals(rs: RatingSet, quality: np.ndarray, bias: np.ndarray,
                                     inconsistency: np.ndarray) -> np.ndarray:
    """Per stimulus, its content's ambiguity when the fitted model has none (SUREAL's P.910
    fallback is content-oblivious): the residual variance of all the content's ratings
    beyond the raters' inconsistency, pooled over the content so that one stimulus's
    scatter hardly moves it."""
    resid = rs.scores - quality[:, None, None] - bias[None, :, None]
    finite = np.isfinite(resid)
    expected = np.broadcast_to((inconsistency ** 2)[None, :, None], resid.shape)
    extra = np.where(finite, resid * resid - expected, 0.0).sum(axis=(1, 2))
    count = finite.sum(axis=(1, 2))
    refs = rs.stimuli["reference"].to_numpy()
    out = np.zeros(rs.n_stimuli)
    for r in np.unique(refs):
        rows = refs == r
        out[rows] = np.sqrt(max(extra[rows].sum() / max(count[rows].sum(), 1), 0.0))
    return out


def allocation_fit(rs: RatingSet, *, n_boot: int = 200, seed: int = 0) -> AllocationFit:
    """Fit the analysis' model to the ratings so far and keep what a plan needs: each
    condition's DMOS half-width as the model predicts it from the ratings' variances and
    counts (:func:`rating_variance`), put on the scale of the analysis' bootstrap intervals
    (their median ratio), and the share of it from the condition's own ratings."""
    res = fit_scores(rs, "mle", n_boot=n_boot, seed=seed)
    ref = rs.reference_index()
    hidden = rs.hidden_reference_mask
    n = np.isfinite(rs.scores).sum(axis=(1, 2)).astype(float)
    s2 = rating_variance(rs, res)
    own = s2 / np.maximum(n, 1)
    has = (ref >= 0) & ~hidden
    r = np.maximum(ref, 0)
    refpart = np.where(has, s2[r] / np.maximum(n[r], 1), 0.0)
    share = np.where(has, own / (own + refpart), 1.0)
    model = np.sqrt(own + refpart)
    boot = np.asarray(res.dmos_halfwidth, dtype=float)
    ratio = boot[has] / model[has]
    ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
    scale = float(np.median(ratio)) if ratio.size else 1.0
    half = np.where(has, scale * model, 0.0)
    return AllocationFit(rs.stimulus_ids, half, share, ref, hidden.copy(), n)


def forecast_halfwidth(fit: AllocationFit, counts: np.ndarray,
                      reference_counts: np.ndarray | None = None) -> np.ndarray:
    """Forecast half-widths when the stimuli have ``counts`` ratings instead of those the
    fit used: each part of a condition's variance scales with n_fit / n.
    ``reference_counts``: per condition, its reference's count (default: from ``counts``)."""
    counts = np.asarray(counts, dtype=float)
    n0 = np.maximum(fit.ratings, 1.0)
    r = np.maximum(fit.reference, 0)
    ref_n = counts[r] if reference_counts is None else reference_counts
    scale = fit.own_share * n0 / np.maximum(counts, 1.0) + \
        (1.0 - fit.own_share) * np.where(fit.reference >= 0, n0[r] / np.maximum(ref_n, 1.0), 0)
    return np.where(fit.condition_mask(), fit.halfwidth * np.sqrt(scale), 0.0)


def plan_block(fit: AllocationFit, size: int, *, pending: np.ndarray | None = None,
               max_per_block: int = MAX_PER_BLOCK, power: float = POWER,
               last: int | None = None) -> np.ndarray:
    """How many times each stimulus appears in the next block of ``size`` trials.

    ``pending``: ratings per stimulus planned in blocks issued since the fit (they will
    arrive; counting them keeps two participants from both getting the same stimuli).
    ``last``: the index of the stimulus shown just before the block. No stimulus gets more
    than half the block (rounded up; ``last`` rounded down), so the block can be ordered
    without a stimulus twice in a row."""
    e = len(fit.stimulus_ids)
    if size < 1:
        raise AnalysisError("a block needs at least one trial")
    if size > e * max_per_block:
        raise AnalysisError(f"a block of {size} trials cannot hold each of {e} stimuli at most "
                            f"{max_per_block} times")
    counts = fit.ratings.astype(float) + (0 if pending is None else np.asarray(pending, float))
    block = np.zeros(e, dtype=int)
    cond = fit.condition_mask()
    ref = np.where(cond, fit.reference, 0)
    top = float(fit.halfwidth.max()) or 1.0  # keeps h ** power in range

    def objective(own: np.ndarray, ref_n: np.ndarray) -> np.ndarray:
        return (forecast_halfwidth(fit, own, ref_n) / top) ** power

    cap = np.full(e, min(max_per_block, (size + 1) // 2))
    if last is not None:
        cap[last] = min(max_per_block, size // 2)
    for _ in range(size):
        ref_now = counts[ref]
        now = objective(counts, ref_now)
        gain = np.where(cond, now - objective(counts + 1.0, ref_now), 0.0)
        # a reference's extra rating narrows every condition that depends on it
        from_ref = np.where(cond, now - objective(counts, ref_now + 1.0), 0.0)
        gain = gain + np.bincount(ref[cond], weights=from_ref[cond], minlength=e)
        gain[block >= cap] = -np.inf
        pick = int(np.argmax(gain))
        block[pick] += 1
        counts[pick] += 1.0
    return block
