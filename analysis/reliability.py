"""How much raters agree: ICC, inter-rater correlations, intra-rater repeatability."""

from __future__ import annotations

import itertools
import threading
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .data import RatingSet, balanced_subset
from .errors import AnalysisError
from .icc import icc_unbalanced, interval_text

# pingouin >= 0.7 names the two-way ICCs after McGraw & Wong; older versions after Shrout & Fleiss.
_ICC_NAMES = {"ICC(2,k)": ("ICC(A,k)", "ICC2k"), "ICC(3,k)": ("ICC(C,k)", "ICC3k"),
              "ICC(2,1)": ("ICC(A,1)", "ICC2"), "ICC(3,1)": ("ICC(C,1)", "ICC3")}


@dataclass
class Reliability:
    """ICCs (with 95% CIs), the inter-rater Pearson matrix and intra-rater repeatability.

    ``method`` says how the ICCs were computed: pingouin's ANOVA on complete data, or REML
    variance components on all cells when some rater skipped some stimuli (then
    ``complete_case`` holds pingouin's values on the stimuli every rater rated, with their
    count, when there are at least 3). ``subset`` describes the ratings the ICCs and the
    inter-rater matrix used when not all of them (an unbalanced design: the first rating of
    each stimulus per rater); intra-rater repeatability always uses every repetition.
    """

    icc: dict[str, float]
    icc_ci: dict[str, tuple[float, float]]
    n_targets: int
    inter_rater: pd.DataFrame
    intra_rater: pd.Series
    method: str = "pingouin (two-way ANOVA, complete data)"
    n_stimuli: int = 0
    n_raters: int = 0
    n_cells: int = 0
    complete_case: dict | None = None
    subset: str = ""
    # pingouin's ICCs on the distorted stimuli alone ({"icc", "ci", "n_stimuli"}), when hidden
    # references are among the targets and the data are complete: a hidden reference is easy
    # to agree on, so the ICC over all stimuli is higher than over the distortions a metric
    # is compared on (a paper comparing ICC(2,1) across studies needs to know which)
    distorted_only: dict | None = None


_PINGOUIN_OPTIONS = threading.Lock()


def icc_from_long(data: pd.DataFrame, targets: str, raters: str,
                  ratings: str) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """ICC(2,k), ICC(3,k), ICC(2,1), ICC(3,1) via pingouin, whichever naming it uses.

    Targets that some rater did not rate are dropped (pingouin needs a complete table).
    """
    import pingouin as pg

    # pingouin rounds the CI95 column to 2 decimals for display (its global options): the
    # report shows 3, and at high ICC [1.00, 1.00] excluded the estimate. Unrounded here,
    # under a lock, since the option is process-wide and the server analyses in a thread.
    with _PINGOUIN_OPTIONS, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        before = pg.options.get("round.column.CI95")
        pg.options["round.column.CI95"] = None
        try:
            table = pg.intraclass_corr(data=data, targets=targets, raters=raters,
                                       ratings=ratings, nan_policy="omit")
        finally:
            pg.options["round.column.CI95"] = before
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


def reliability(rs: RatingSet, *, n_boot: int = 200, seed: int = 0) -> Reliability:
    """All reliability figures of a rating set (ratings averaged over repetitions; in an
    unbalanced design ICC and inter-rater r on the first rating per stimulus and rater)."""
    intra = pd.Series(repetition_correlation(rs.scores), index=rs.raters, name="intra_rater_r")
    sub, text = balanced_subset(rs)
    out = _agreement(sub, intra, n_boot=n_boot, seed=seed)
    out.subset = text
    out.distorted_only = _distorted_only(sub)
    return out


def _distorted_only(rs: RatingSet) -> dict | None:
    """pingouin's ICCs without the hidden references (complete data only; None otherwise)."""
    hidden = rs.hidden_reference_mask
    if not hidden.any():
        return None
    means = rs.rater_means()[~hidden]
    if means.shape[0] < 3 or rs.n_raters < 2 or not np.isfinite(means).all():
        return None
    long = pd.DataFrame(means, columns=rs.raters).stack().rename("rating").rename_axis(
        ["stimulus", "rater"]).reset_index()
    icc, ci = icc_from_long(long, "stimulus", "rater", "rating")
    return {"icc": icc, "ci": ci, "n_stimuli": int(means.shape[0])}


def _agreement(rs: RatingSet, intra: pd.Series, *, n_boot: int, seed: int) -> Reliability:
    """ICCs and the inter-rater matrix of ``rs`` (pingouin when complete, REML otherwise)."""
    means = rs.rater_means()
    rated = np.isfinite(means)
    n_stim = int(rated.any(axis=1).sum())
    if rs.n_raters < 2 or n_stim < 3:
        raise AnalysisError(f"ICC needs at least 3 stimuli and 2 raters (have {n_stim} "
                            f"stimuli, {rs.n_raters} raters)")
    complete_rows = rated.all(axis=1)
    complete = int(complete_rows.sum())
    inter = pd.DataFrame(means, columns=rs.raters).corr(method="pearson", min_periods=3)
    cells = int(rated.sum())
    if complete == n_stim:
        long = pd.DataFrame(means, index=rs.stimulus_ids, columns=rs.raters).stack().rename(
            "rating").rename_axis(["stimulus", "rater"]).reset_index()
        icc, ci = icc_from_long(long, "stimulus", "rater", "rating")
        return Reliability(icc, ci, complete, inter, intra, n_stimuli=n_stim,
                           n_raters=rs.n_raters, n_cells=cells)
    icc, ci = icc_unbalanced(means, n_boot=n_boot, seed=seed)
    cc = None
    if complete >= 3:
        sub = means[complete_rows]
        long = pd.DataFrame(sub, columns=rs.raters).stack().rename("rating").rename_axis(
            ["stimulus", "rater"]).reset_index()
        cc_icc, cc_ci = icc_from_long(long, "stimulus", "rater", "rating")
        cc = {"icc": cc_icc, "ci": cc_ci, "n_stimuli": complete}
    method = (f"REML variance components on all {cells} stimulus-rater cells "
              f"({cells / (n_stim * rs.n_raters):.0%} of {n_stim} x {rs.n_raters}); "
              f"{interval_text(n_boot)}")
    return Reliability(icc, ci, complete, inter, intra, method=method, n_stimuli=n_stim,
                       n_raters=rs.n_raters, n_cells=cells, complete_case=cc)
