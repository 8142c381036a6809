"""How much raters agree: ICC, inter-rater correlations, intra-rater repeatability."""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .data import RatingSet
from .errors import AnalysisError

# pingouin >= 0.7 names the two-way ICCs after McGraw & Wong; older versions after Shrout & Fleiss.
_ICC_NAMES = {"ICC(2,k)": ("ICC(A,k)", "ICC2k"), "ICC(3,k)": ("ICC(C,k)", "ICC3k"),
              "ICC(2,1)": ("ICC(A,1)", "ICC2"), "ICC(3,1)": ("ICC(C,1)", "ICC3")}


@dataclass
class Reliability:
    """ICCs (with 95% CIs), the inter-rater Pearson matrix and intra-rater repeatability."""

    icc: dict[str, float]
    icc_ci: dict[str, tuple[float, float]]
    n_targets: int
    inter_rater: pd.DataFrame
    intra_rater: pd.Series


def icc_from_long(data: pd.DataFrame, targets: str, raters: str,
                  ratings: str) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """ICC(2,k), ICC(3,k), ICC(2,1), ICC(3,1) via pingouin, whichever naming it uses.

    Targets that some rater did not rate are dropped (pingouin needs a complete table).
    """
    import pingouin as pg

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        table = pg.intraclass_corr(data=data, targets=targets, raters=raters, ratings=ratings,
                                   nan_policy="omit")
    table = table.set_index("Type")
    icc, ci = {}, {}
    for ours, names in _ICC_NAMES.items():
        name = next((n for n in names if n in table.index), None)
        if name is None:
            raise AnalysisError(f"pingouin did not report {ours} (looked for {names}); "
                                "check the installed pingouin version")
        icc[ours] = float(table.loc[name, "ICC"])
        lo, hi = table.loc[name, "CI95"] if "CI95" in table.columns else \
            table.loc[name, "CI95%"]
        ci[ours] = (float(lo), float(hi))
    return icc, ci


def repetition_correlation(scores: np.ndarray) -> np.ndarray:
    """Per rater, the mean Pearson r between their repetitions (over stimuli rated in both)."""
    _, n_raters, n_rep = scores.shape
    out = np.full(n_raters, np.nan)
    for s in range(n_raters):
        rs = []
        for a, b in itertools.combinations(range(n_rep), 2):
            x, y = scores[:, s, a], scores[:, s, b]
            ok = np.isfinite(x) & np.isfinite(y)
            if ok.sum() >= 3 and x[ok].std() > 0 and y[ok].std() > 0:
                rs.append(np.corrcoef(x[ok], y[ok])[0, 1])
        if rs:
            out[s] = float(np.mean(rs))
    return out


def reliability(rs: RatingSet) -> Reliability:
    """All reliability figures of a rating set (ratings averaged over repetitions)."""
    means = rs.rater_means()
    long = pd.DataFrame(means, index=rs.stimulus_ids, columns=rs.raters).stack().rename(
        "rating").rename_axis(["stimulus", "rater"]).reset_index()
    complete = np.isfinite(means).all(axis=1).sum()
    if complete < 3 or rs.n_raters < 2:
        raise AnalysisError(
            f"ICC needs at least 3 stimuli rated by every rater and 2 raters (have {complete} "
            f"complete stimuli, {rs.n_raters} raters)")
    icc, ci = icc_from_long(long, "stimulus", "rater", "rating")
    inter = pd.DataFrame(means, columns=rs.raters).corr(method="pearson", min_periods=3)
    intra = pd.Series(repetition_correlation(rs.scores), index=rs.raters, name="intra_rater_r")
    return Reliability(icc, ci, int(complete), inter, intra)
