"""Screening out raters who disagree with the panel (``--outliers``).

- ``p913`` (default): ITU-T P.913's correlation screening against the leave-one-out panel,
  iterated, confirmed by the MLE inconsistency estimate; robust to rater bias and to masking
  (see :mod:`analysis.screening`).
- ``grubbs``: the CGVQM+D paper's rule, kept to reproduce it: iterative two-sided Grubbs'
  test on each rater's mean absolute deviation from the panel mean (ratings averaged over
  repetitions); the most extreme rater is removed while the test rejects at ``alpha``. The
  deviation mixes rater bias (which the MLE models) with inconsistency, so a consistent rater
  with an offset can be removed and several offset raters can mask a random one.
- ``bt500``: ITU-R BT.500 kurtosis-based screening (as implemented in SUREAL).
- ``none``.
"""

from __future__ import annotations

import contextlib
import io
import logging
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from .data import RatingSet
from .errors import AnalysisError

log = logging.getLogger(__name__)

METHODS = ("p913", "grubbs", "bt500", "none")
DEFAULT_METHOD = "p913"


@dataclass(frozen=True)
class RemovedRater:
    """A rater taken out, with the statistic that condemned them."""

    rater: str
    method: str
    statistic: float
    critical: float
    value: float
    reason: str


@dataclass
class OutlierResult:
    """Who was removed, who was kept, and each rater's screening value."""

    method: str
    removed: list[RemovedRater]
    kept: list[int]
    deviation: dict[str, float] = field(default_factory=dict)
    # Per rater (all of them): the statistics of the rule, the decision and, for removals and
    # near-misses, why.
    table: pd.DataFrame | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def removed_names(self) -> list[str]:
        return [r.rater for r in self.removed]


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
    """Each rater's mean absolute deviation from the panel mean, over the stimuli they rated."""
    panel = np.nanmean(rater_means, axis=1, keepdims=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
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
            rater=rs.raters[who], method="grubbs", statistic=g, critical=crit,
            value=float(dev[k]),
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


def bt500_rejection(rs: RatingSet) -> tuple[list[bool], list[float], list[float]]:
    """SUREAL's ITU-R BT.500 screening: (rejected?, P+Q ratio, |P-Q|/(P+Q)) per rater."""
    from sureal.dataset_reader import RawDatasetReader
    from sureal.subjective_model import SubjrejMosModel

    from .sureal_io import sureal_namespace

    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(), \
            np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        result = SubjrejMosModel(RawDatasetReader(sureal_namespace(rs))).run_modeling()
    return (list(map(bool, result["observer_rejected"])),
            [float(v) for v in result["observer_rejected_1st_stats"]],
            [float(v) for v in result["observer_rejected_2nd_stats"]])


def bt500_screen(rs: RatingSet) -> OutlierResult:
    """ITU-R BT.500 kurtosis screening: reject when (P+Q)/N > 0.05 and |P-Q|/(P+Q) < 0.3."""
    rejected, first, second = bt500_rejection(rs)
    removed = [
        RemovedRater(
            rater=rs.raters[s], method="bt500", statistic=first[s], critical=0.05,
            value=second[s],
            reason=(f"{first[s]:.1%} of the votes lie outside the BT.500 bounds (> 5%) and "
                    f"they are not one-sided (|P-Q|/(P+Q) = {second[s]:.2f} < 0.3)"),
        )
        for s in range(rs.n_raters) if rejected[s]
    ]
    kept = [s for s in range(rs.n_raters) if not rejected[s]]
    table = pd.DataFrame({"outside_share": first, "one_sidedness": second,
                          "decision": ["removed" if r else "kept" for r in rejected],
                          "reason": [next((x.reason for x in removed if x.rater == name), "")
                                     for name in rs.raters]},
                         index=pd.Index(rs.raters, name="rater"))
    return OutlierResult("bt500", removed, kept, {r: f for r, f in zip(rs.raters, first,
                                                                      strict=True)},
                         table=table)


def check_alpha(alpha: float) -> float:
    """A significance level must be a number in (0, 0.5); anything else is refused."""
    try:
        value = float(alpha)
    except (TypeError, ValueError):
        raise AnalysisError(f"alpha {alpha!r} is not a number") from None
    if not (0.0 < value < 0.5):
        raise AnalysisError(f"alpha must lie between 0 and 0.5 (e.g. 0.05), got {alpha!r}")
    return value


def screen_raters(rs: RatingSet, method: str = DEFAULT_METHOD, *,
                  alpha: float = 0.05) -> OutlierResult:
    """Run the chosen screening; ``none`` keeps everyone."""
    alpha = check_alpha(alpha)
    if method == "p913":
        from .screening import p913_screen

        result = p913_screen(rs)
    elif method == "grubbs":
        result = grubbs_screen(rs, alpha)
    elif method == "bt500":
        result = bt500_screen(rs)
    elif method == "none":
        result = OutlierResult("none", [], list(range(rs.n_raters)),
                               table=pd.DataFrame({"decision": "kept", "reason": ""},
                                                  index=pd.Index(rs.raters, name="rater")))
    else:
        raise AnalysisError(f"unknown outlier method {method!r}; use one of {', '.join(METHODS)}")
    if len(result.kept) < 2:
        raise AnalysisError(f"outlier screening ({method}) left fewer than 2 raters; use "
                            "--outliers none to inspect the data")
    return result
