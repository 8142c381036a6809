"""``grubbs``: the CGVQM+D paper's rule, kept to reproduce it.

Iterative two-sided Grubbs' test on each rater's mean absolute deviation from the panel mean
(ratings averaged over repetitions); the most extreme rater is removed while the test rejects
at ``alpha``. The deviation mixes rater bias (which the MLE models) with inconsistency, so a
consistent rater with an offset can be removed and several offset raters can mask a random one.
"""

from __future__ import annotations

import logging
import warnings

import numpy as np
import pandas as pd
from scipy import stats

from ..data import RatingSet
from .result import OutlierResult, RemovedRater
from .rule import ScreeningRule

log = logging.getLogger(__name__)


def grubbs_critical(n: int, alpha: float = 0.05, *, two_sided: bool = True) -> float:
    """Critical value of Grubbs' statistic G for ``n`` values.

    G_crit = (n - 1) / sqrt(n) * sqrt(t^2 / (n - 2 + t^2)) with t the upper
    alpha/(2n) (two-sided) or alpha/n (one-sided) quantile of Student's t, n - 2 d.o.f.
    """
    if n < 3:
        raise ValueError("Grubbs' test needs at least 3 values")
    p = alpha / (2 * n) if two_sided else alpha / n
    t = stats.t.isf(p, n - 2)
    return float((n - 1) / np.sqrt(n) * np.sqrt(t * t / (n - 2 + t * t)))


def grubbs_statistic(values: np.ndarray) -> tuple[float, int]:
    """G = max |x - mean| / s (sample s.d.) and the index of that value."""
    x = np.asarray(values, dtype=float)
    sd = x.std(ddof=1)
    if not sd > 0:
        return 0.0, 0
    z = np.abs(x - x.mean()) / sd
    k = int(np.argmax(z))
    return float(z[k]), k


def rater_deviation(rater_means: np.ndarray) -> np.ndarray:
    """Each rater's mean absolute deviation from the panel mean, over the stimuli they rated
    (a stimulus no rater here rated has no panel mean and counts for nobody)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the all-NaN rows and columns
        panel = np.nanmean(rater_means, axis=1, keepdims=True)
        return np.nanmean(np.abs(rater_means - panel), axis=0)


def grubbs_screen(rs: RatingSet, alpha: float = 0.05) -> OutlierResult:
    """Iterative two-sided Grubbs' test on rater deviation (see module docstring)."""
    means = rs.rater_means()
    kept = list(range(rs.n_raters))
    removed: list[RemovedRater] = []
    first_dev: dict[str, float] = {}
    while len(kept) >= 3:
        dev = rater_deviation(means[:, kept])
        if not first_dev:
            first_dev = {rs.raters[k]: float(d) for k, d in zip(kept, dev, strict=True)}
        g, k = grubbs_statistic(dev)
        crit = grubbs_critical(len(kept), alpha)
        if not g > crit:
            break
        side = "larger" if dev[k] > dev.mean() else "smaller"
        who = kept.pop(k)
        removed.append(RemovedRater(
            rater=rs.raters[who], method="grubbs", statistic_name="grubbs_g", statistic=g,
            critical=crit, second_name="deviation", second=float(dev[k]),
            second_critical=float("nan"),
            reason=(f"mean absolute deviation {dev[k]:.3g} from the panel mean is {side} than "
                    f"the others' (Grubbs G = {g:.3f} > critical {crit:.3f} at alpha {alpha}, "
                    f"n = {len(kept) + 1})"),
        ))
        log.info("Grubbs: removed rater %s (G=%.3f > %.3f)", rs.raters[who], g, crit)
    if not first_dev and kept:
        dev = rater_deviation(means[:, kept])
        first_dev = {rs.raters[k]: float(d) for k, d in zip(kept, dev, strict=True)}
    table = pd.DataFrame({"deviation": pd.Series(first_dev)}).reindex(rs.raters)
    table["decision"] = ["removed" if r in {x.rater for x in removed} else "kept"
                         for r in rs.raters]
    table["reason"] = [next((x.reason for x in removed if x.rater == r), "")
                       for r in rs.raters]
    if len(kept) >= 3:
        dev = rater_deviation(means[:, kept])
        g, k = grubbs_statistic(dev)
        crit = grubbs_critical(len(kept), alpha)
        if g > 0.9 * crit:
            name = rs.raters[kept[k]]
            table.loc[name, "reason"] = (f"near-miss, kept: Grubbs G = {g:.3f} is within 10% "
                                         f"of the critical {crit:.3f} (n = {len(kept)})")
    table.index.name = "rater"
    return OutlierResult("grubbs", removed, kept, first_dev, table=table)


RULE = ScreeningRule(
    name="grubbs", order=1, summary="the CGVQM+D paper's rule: Grubbs' test on rater deviation",
    screen=grubbs_screen, uses_alpha=True, min_raters=3)
