"""SUREAL's subjective models run quietly and checked, and the plain-means estimates.

The score models (:mod:`analysis.scores`) and the rater screening rules
(:mod:`analysis.screening`) both fit SUREAL's models and fall back to plain means, so the
fitting lives here, below both of them.
"""

from __future__ import annotations

import contextlib
import io
import warnings

import numpy as np
from scipy import stats

from .data import RatingSet
from .errors import AnalysisError
from .sureal_io import sureal_namespace


def quiet_sureal(model_cls: type, rs: RatingSet) -> dict:
    """Run one of SUREAL's subjective models on ``rs`` with its printing and warnings silenced."""
    from sureal.dataset_reader import RawDatasetReader

    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(), \
            np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        return model_cls(RawDatasetReader(sureal_namespace(rs))).run_modeling()


def mos_and_t(scores: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over all votes (raters x repetitions), t-based 95% half-width, vote count."""
    flat = scores.reshape(scores.shape[0], -1)
    n = np.isfinite(flat).sum(axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(flat, axis=1)
        sd = np.nanstd(flat, axis=1, ddof=1)
        t = stats.t.ppf(0.975, np.maximum(n - 1, 1))
        half = np.where(n > 1, t * sd / np.sqrt(np.maximum(n, 1)), np.nan)
    return mean, half, n


def rater_stats_from_means(rs: RatingSet, quality: np.ndarray) -> tuple[np.ndarray, ...]:
    """Bias (mean residual) and inconsistency (residual s.d.) per rater, with 95% CIs."""
    resid = rs.scores - quality[:, None, None]
    flat = np.moveaxis(resid, 1, 0).reshape(rs.n_raters, -1)
    n = np.isfinite(flat).sum(axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        bias = np.nanmean(flat, axis=1)
        sd = np.nanstd(flat - bias[:, None], axis=1, ddof=1)
        half = stats.t.ppf(0.975, np.maximum(n - 1, 1)) * sd / np.sqrt(np.maximum(n, 1))
        lo = np.sqrt((n - 1) * sd**2 / stats.chi2.ppf(0.975, np.maximum(n - 1, 1)))
        hi = np.sqrt((n - 1) * sd**2 / stats.chi2.ppf(0.025, np.maximum(n - 1, 1)))
    return bias, np.c_[bias - half, bias + half], sd, np.c_[lo, hi]


def run_sureal(cls: type, rs: RatingSet) -> dict:
    """:func:`quiet_sureal`, with a numerical failure returned as ``{"error": reason}``."""
    try:
        return quiet_sureal(cls, rs)
    except (ValueError, AssertionError, FloatingPointError, np.linalg.LinAlgError) as exc:
        return {"error": str(exc) or type(exc).__name__}


def implausible(out: dict, rs: RatingSet) -> str | None:
    """Why a SUREAL result cannot be used (its own error, non-finite or absurd values), or
    None when it can: finite quality inside a generous band around the scale, spreads below
    its range. Every SUREAL fit goes through this, since a diverged fit returns numbers."""
    if "error" in out:
        return f"SUREAL failed: {out['error']}"
    span = rs.scale_max - rs.scale_min
    q = np.asarray(out.get("quality_scores", []), dtype=float)
    if q.size != rs.n_stimuli:
        return f"SUREAL returned {q.size} quality scores for {rs.n_stimuli} stimuli"
    if not np.isfinite(q).all():
        return f"{int((~np.isfinite(q)).sum())} quality score(s) are not finite"
    if (q < rs.scale_min - span).any() or (q > rs.scale_max + span).any():
        return (f"quality scores reach {q.min():g}..{q.max():g}, far outside the scale "
                f"{rs.scale_min:g}..{rs.scale_max:g}")
    for key in ("observer_inconsistency", "content_ambiguity"):
        v = np.asarray(out.get(key, []), dtype=float)
        if v.size and (not np.isfinite(v).all() or (v > span).any()):
            return f"{key.replace('_', ' ')} is not finite or exceeds the scale's range"
    return None


def plausible(out: dict, rs: RatingSet) -> bool:
    """True when :func:`implausible` finds nothing wrong with the SUREAL result ``out``."""
    return implausible(out, rs) is None


def bt500_rejection(rs: RatingSet) -> tuple[list[bool], list[float], list[float]]:
    """SUREAL's ITU-R BT.500 screening: (rejected?, P+Q ratio, |P-Q|/(P+Q)) per rater."""
    from sureal.subjective_model import SubjrejMosModel

    result = run_sureal(SubjrejMosModel, rs)
    if "error" in result:
        raise AnalysisError(f"SUREAL's BT.500 screening failed on these ratings "
                            f"({result['error']}); use another --outliers or --model")
    return (list(map(bool, result["observer_rejected"])),
            [float(v) for v in result["observer_rejected_1st_stats"]],
            [float(v) for v in result["observer_rejected_2nd_stats"]])
