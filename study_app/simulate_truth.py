"""What an analysis of simulated ratings can recover: the mean of *clipped* ratings.

Ratings are clipped at the ends of the scale, so a hidden reference of true quality 97 rated
by a panel with biases of +-12 and noise of s.d. 8 averages well below 97: no estimator can
see past the clip. The truth file therefore gives, beside each stimulus's latent quality, the
expected rating of the regular (non-outlier) raters and the DMOS made from those
expectations, which is what the analysis estimates (``bench_coverage.py`` defines its truth
the same way). Standard library only: ``simulate`` runs in the participant's lean install.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping


def _cdf(x: float) -> float:
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


def _pdf(x: float) -> float:
    return math.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi)


def expected_clipped(mean: float, sd: float, lo: float, hi: float) -> float:
    """E[clip(X, lo, hi)] for X ~ N(mean, sd^2)."""
    if sd <= 0:
        return min(max(mean, lo), hi)
    a, b = (lo - mean) / sd, (hi - mean) / sd
    below, inside = _cdf(a), _cdf(b) - _cdf(a)
    return lo * below + hi * (1.0 - _cdf(b)) + mean * inside + sd * (_pdf(a) - _pdf(b))


def expected_rating(quality: float, raters: Iterable[tuple[float, float]], ambiguity: float,
                    scale: tuple[float, float]) -> float:
    """The panel's mean expected rating of a stimulus of latent ``quality`` (on the
    higher-is-better reading): ``raters`` are (bias, inconsistency) of the regular raters,
    whose noise adds to the content's ``ambiguity``."""
    lo, hi = scale
    values = [expected_clipped(quality + bias, math.hypot(sigma, ambiguity), lo, hi)
              for bias, sigma in raters]
    return sum(values) / len(values) if values else float("nan")


def recoverable_dmos(expected: Mapping[str, float], reference_of: Mapping[str, str],
                     top: float) -> dict[str, float]:
    """DMOS = E(v) - E(ref(v)) + top of the scale, per stimulus whose hidden reference was
    rated (P.910's definition, on expected ratings)."""
    return {sid: expected[sid] - expected[ref] + top for sid, ref in reference_of.items()
            if sid in expected and ref in expected}
