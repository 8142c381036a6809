"""Correlation statistics computed column by column, for many resamples at once.

Bootstrap and split-half loops would call scipy once per resample; these functions take
``(n, B)`` arrays and return ``B`` values, so 1000 resamples are a few array operations.
Each matches its scipy.stats counterpart (Pearson, Spearman with average ranks, Kendall tau-b).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

_PAIR_BUDGET = 4_000_000  # pair x column elements per Kendall chunk (bounded memory)


def _as_columns(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return x[:, None] if x.ndim == 1 else x


def pearson_columns(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Pearson r of every column of ``x`` with the same column of ``y``."""
    x, y = _as_columns(x), _as_columns(y)
    xc = x - x.mean(axis=0)
    yc = y - y.mean(axis=0)
    num = (xc * yc).sum(axis=0)
    den = np.sqrt((xc * xc).sum(axis=0) * (yc * yc).sum(axis=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


def spearman_columns(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Spearman rho (average ranks for ties) column by column."""
    x, y = _as_columns(x), _as_columns(y)
    return pearson_columns(stats.rankdata(x, axis=0), stats.rankdata(y, axis=0))


def kendall_columns(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Kendall tau-b column by column (pairs compared in bounded-memory chunks)."""
    x, y = _as_columns(x), _as_columns(y)
    n, b = x.shape
    i, j = np.triu_indices(n, k=1)
    if i.size == 0:
        return np.full(b, np.nan)
    step = max(1, _PAIR_BUDGET // i.size)
    out = np.empty(b)
    for start in range(0, b, step):
        sl = slice(start, min(b, start + step))
        dx = np.sign(x[i, sl] - x[j, sl])
        dy = np.sign(y[i, sl] - y[j, sl])
        s = (dx * dy).sum(axis=0)
        nx = np.abs(dx).sum(axis=0)
        ny = np.abs(dy).sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[sl] = np.where((nx > 0) & (ny > 0), s / np.sqrt(nx * ny), np.nan)
    return out


def rmse_columns(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Root mean squared difference column by column."""
    x, y = _as_columns(x), _as_columns(y)
    return np.sqrt(((x - y) ** 2).mean(axis=0))


def all_columns(x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """PLCC, SRCC, KRCC and RMSE of ``y`` against ``x`` column by column."""
    return {
        "plcc": pearson_columns(x, y),
        "srcc": spearman_columns(x, y),
        "krcc": kendall_columns(x, y),
        "rmse": rmse_columns(x, y),
    }


def percentile_interval(values: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Equal-tailed percentile interval of a resampled statistic, NaNs ignored."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return (float("nan"), float("nan"))
    tail = (1.0 - level) / 2.0 * 100.0
    lo, hi = np.percentile(values, [tail, 100.0 - tail])
    return float(lo), float(hi)


def all_columns_masked(x: np.ndarray, y: np.ndarray) -> tuple[dict[str, np.ndarray],
                                                                np.ndarray]:
    """:func:`all_columns` where each column uses only the rows finite in both (unbalanced
    designs: a split-half leaves some stimuli unrated in one half). Returns the statistics
    and the number of rows each column used (columns with fewer than 3 get NaN)."""
    x, y = _as_columns(x), _as_columns(y)
    ok = np.isfinite(x) & np.isfinite(y)
    n = ok.sum(axis=0)
    full = ok.all(axis=0)
    out = {k: np.full(x.shape[1], np.nan) for k in ("plcc", "srcc", "krcc", "rmse")}
    if full.any():
        for key, vals in all_columns(x[:, full], y[:, full]).items():
            out[key][full] = vals
    for j in np.flatnonzero(~full & (n >= 3)):
        rows = ok[:, j]
        for key, vals in all_columns(x[rows, j], y[rows, j]).items():
            out[key][j] = vals[0]
    return out, n
