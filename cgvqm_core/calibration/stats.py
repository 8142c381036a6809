"""Agreement of metric scores with human scores, and intervals over repeated splits."""

from __future__ import annotations

import numpy as np
from scipy import stats


def correlations(pred: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """Signed PLCC, SRCC, KRCC (tau-b) and RMSE of ``pred`` against ``target``.

    NaN where fewer than 3 videos or a constant input make a correlation undefined.
    """
    x = np.asarray(pred, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64)
    out = {"plcc": np.nan, "srcc": np.nan, "krcc": np.nan,
           "rmse": float(np.sqrt(np.mean((x - y) ** 2))) if x.size else np.nan}
    if x.size >= 3 and np.ptp(x) > 0 and np.ptp(y) > 0:
        out["plcc"] = float(stats.pearsonr(x, y).statistic)
        out["srcc"] = float(stats.spearmanr(x, y).statistic)
        out["krcc"] = float(stats.kendalltau(x, y).statistic)
    return out


def interval(values: np.ndarray, bounds: tuple[float, float] = (-np.inf, np.inf)
             ) -> dict[str, float]:
    """Mean over repetitions with a t-based 95% interval of the mean (clipped to the
    statistic's ``bounds``), and the 2.5-97.5% percentile range of the repetitions
    themselves (where one split is likely to land)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    n = v.size
    if n == 0:
        return {"mean": np.nan, "ci95_low": np.nan, "ci95_high": np.nan,
                "p2.5": np.nan, "p97.5": np.nan, "sd": np.nan, "n": 0}
    mean = float(v.mean())
    sd = float(v.std(ddof=1)) if n > 1 else 0.0
    half = float(stats.t.ppf(0.975, n - 1) * sd / np.sqrt(n)) if n > 1 else np.nan
    lo, hi = bounds
    return {"mean": mean, "ci95_low": max(mean - half, lo), "ci95_high": min(mean + half, hi),
            "p2.5": float(np.percentile(v, 2.5)), "p97.5": float(np.percentile(v, 97.5)),
            "sd": sd, "n": n}
