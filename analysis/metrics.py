"""Metric versus humans: logistic mapping, correlations with bootstrap CIs, significance.

Each metric's scores are mapped to DMOS with the 5-parameter logistic
``q' = b1 (0.5 - 1 / (1 + exp(b2 (q - b3)))) + b4 q + b5`` (fitted on standardised scores from
a data-driven start, within bounds; when the fit fails or is not monotone over the data, a
straight line is used and the table says so). PLCC and RMSE use the mapped scores, SRCC and
KRCC the raw ones (their sign is reported as is; comparisons use the fit-based PLCC, which
does not depend on whether a metric is higher- or lower-is-better). Bootstrap resamples
stimuli; every statistic of every resample is computed in one vectorised pass.
"""

from __future__ import annotations

import itertools
import logging
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import optimize

from .data import InputProblem
from .errors import AnalysisError
from .stats import (
    all_columns,
    kendall_columns,
    pearson_columns,
    percentile_interval,
    rmse_columns,
    spearman_columns,
)

log = logging.getLogger(__name__)

_REQUIRED = ("stimulus", "metric", "score")
STATS = ("plcc", "srcc", "krcc", "rmse")


# -- input --------------------------------------------------------------------------------
@dataclass
class MetricScores:
    """Scores of one or more metrics, one row per (metric, stimulus)."""

    frame: pd.DataFrame  # columns: stimulus, metric (display id), score, backbone
    problems: list[InputProblem] = field(default_factory=list)

    @property
    def metrics(self) -> list[str]:
        return list(dict.fromkeys(self.frame["metric"]))

    def untrained(self) -> dict[str, str]:
        """Metrics that ran on an untrained (random) backbone -> that backbone value."""
        if "backbone" not in self.frame.columns:
            return {}
        b = self.frame.dropna(subset=["backbone"])
        b = b[b["backbone"].astype(str).str.lower().str.startswith("random")]
        return dict(zip(b["metric"], b["backbone"].astype(str), strict=False))


def metric_id(metric: str, pooling: object) -> str:
    """A metric's display name: ``metric`` plus ``(pooling)`` when a pooling is given."""
    if pooling is None or (isinstance(pooling, float) and np.isnan(pooling)) or pooling == "":
        return str(metric)
    return f"{metric} ({pooling})"


def load_metric_scores(paths: list[str | Path]) -> MetricScores:
    """Read metric score CSVs (DESIGN.md contract 4); bad rows are reported and left out."""
    frames, problems = [], []
    for path in map(Path, paths):
        try:
            f = pd.read_csv(path, dtype={"stimulus": str, "reference": str, "metric": str})
        except FileNotFoundError:
            raise AnalysisError(f"metric scores file {path} does not exist") from None
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
            raise AnalysisError(f"metric scores file {path} is not a readable CSV ({exc})") \
                from None
        missing = [c for c in _REQUIRED if c not in f.columns]
        if missing:
            raise AnalysisError(f"metric scores file {path} lacks column(s) "
                                f"{', '.join(missing)} (needs stimulus, reference, metric, score)")
        f["_source"], f["_row"] = str(path), np.arange(len(f)) + 2
        frames.append(f)
    f = pd.concat(frames, ignore_index=True)
    pooling = f["pooling"] if "pooling" in f.columns else pd.Series([None] * len(f))
    f["metric"] = [metric_id(m, p) for m, p in zip(f["metric"], pooling, strict=True)]
    f["score"] = pd.to_numeric(f["score"], errors="coerce")
    bad = ~np.isfinite(f["score"].to_numpy(dtype=float))
    for _, row in f[bad].iterrows():
        problems.append(InputProblem(row["_source"], int(row["_row"]),
                                     f"score of {row['metric']} for {row['stimulus']} is missing "
                                     "or not a number; row left out"))
    f = f[~bad]
    dup = f.duplicated(["metric", "stimulus"], keep="first")
    for _, row in f[dup].iterrows():
        problems.append(InputProblem(row["_source"], int(row["_row"]),
                                     f"second score of {row['metric']} for {row['stimulus']}; "
                                     "left out"))
    f = f[~dup]
    if "backbone" not in f.columns:
        f["backbone"] = None
    return MetricScores(f.reset_index(drop=True), problems)


# -- logistic mapping ------------------------------------------------------------------------
def logistic5(q: np.ndarray, b1: float, b2: float, b3: float, b4: float, b5: float) -> np.ndarray:
    """The 5-parameter logistic of VQEG / Sheikh et al. (2006)."""
    with np.errstate(over="ignore"):
        return b1 * (0.5 - 1.0 / (1.0 + np.exp(b2 * (q - b3)))) + b4 * q + b5


@dataclass
class Mapping:
    """A fitted monotone mapping from metric score to DMOS."""

    kind: str  # "logistic5" or "linear (fallback)"
    params: tuple[float, ...]
    center: float
    scale: float

    def __call__(self, q: np.ndarray) -> np.ndarray:
        z = (np.asarray(q, dtype=float) - self.center) / self.scale
        if self.kind == "logistic5":
            return logistic5(z, *self.params)
        return self.params[0] * z + self.params[1]


def fit_mapping(q: np.ndarray, y: np.ndarray) -> Mapping:
    """Fit the 5-parameter logistic (bounded, from a robust start) or fall back to a line."""
    q, y = np.asarray(q, dtype=float), np.asarray(y, dtype=float)
    center, scale = float(np.median(q)), float(np.std(q)) or 1.0
    z = (q - center) / scale
    slope, intercept = np.polyfit(z, y, 1) if len(z) >= 2 else (0.0, float(np.mean(y)))
    line = Mapping("linear (fallback)", (float(slope), float(intercept)), center, scale)
    if len(q) < 6:
        return line
    yr = float(np.ptp(y)) or 1.0
    sign = 1.0 if slope >= 0 else -1.0
    lower = [-10 * yr, 1e-2, float(z.min()), -yr, float(y.min()) - 10 * yr]
    upper = [10 * yr, 20.0, float(z.max()), yr, float(y.max()) + 10 * yr]
    best, best_sse = None, np.inf
    for b2 in (1.0, 3.0, 0.3):
        p0 = [sign * yr, b2, float(np.clip(np.median(z), lower[2], upper[2])), 0.0,
              float(np.mean(y))]
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                params, _ = optimize.curve_fit(logistic5, z, y, p0=p0, bounds=(lower, upper),
                                               maxfev=20000)
        except (RuntimeError, ValueError, optimize.OptimizeWarning):
            continue
        sse = float(np.sum((logistic5(z, *params) - y) ** 2))
        if sse < best_sse:
            best, best_sse = params, sse
    if best is None:
        log.warning("logistic fit did not converge; using a linear mapping")
        return line
    grid = logistic5(np.linspace(z.min(), z.max(), 200), *best)
    steps = np.diff(grid)
    if not ((steps >= -1e-9 * yr).all() or (steps <= 1e-9 * yr).all()):
        log.warning("logistic fit is not monotone over the data; using a linear mapping")
        return line
    return Mapping("logistic5", tuple(float(p) for p in best), center, scale)


# -- validation ----------------------------------------------------------------------------
@dataclass
class MetricValidation:
    """Everything the report shows about metrics against DMOS."""

    table: pd.DataFrame  # one row per metric (+ the human ceiling row)
    per_method: pd.DataFrame
    significance: pd.DataFrame  # p-value that row metric's PLCC > column metric's
    better: pd.DataFrame  # bool: row significantly better than column at alpha
    mappings: dict[str, Mapping]
    data: dict[str, pd.DataFrame]  # per metric: stimulus, score, dmos, predicted, method
    problems: list[InputProblem]
    untrained: dict[str, str]
    alpha: float


def _bootstrap(y: np.ndarray, pred: np.ndarray, raw: np.ndarray,
               idx: np.ndarray) -> dict[str, np.ndarray]:
    yb, pb, rb = y[idx].T, pred[idx].T, raw[idx].T
    return {"plcc": pearson_columns(yb, pb), "srcc": spearman_columns(yb, rb),
            "krcc": kendall_columns(yb, rb), "rmse": rmse_columns(yb, pb)}


def validate_metrics(
    dmos: pd.DataFrame,
    scores: MetricScores,
    *,
    n_boot: int = 1000,
    seed: int = 0,
    alpha: float = 0.05,
    ceiling: dict[str, dict[str, float]] | None = None,
) -> MetricValidation:
    """Compare every metric with DMOS (hidden references excluded: their DMOS is fixed)."""
    target = dmos[~dmos["is_hidden_reference"].astype(bool)].set_index("stimulus")
    problems = list(scores.problems)
    rng = np.random.default_rng(seed)
    rows, method_rows, mappings, data, boots = [], [], {}, {}, {}
    for name in scores.metrics:
        m = scores.frame[scores.frame["metric"] == name]
        unknown = m[~m["stimulus"].isin(dmos["stimulus"])]
        for _, row in unknown.iterrows():
            problems.append(InputProblem(row["_source"], int(row["_row"]),
                                         f"{name}: stimulus {row['stimulus']!r} has no DMOS; "
                                         "left out"))
        m = m[m["stimulus"].isin(target.index)]
        if len(m) < 3:
            problems.append(InputProblem(name, None, f"{name}: only {len(m)} stimuli with DMOS; "
                                         "metric not evaluated"))
            continue
        q = m["score"].to_numpy(dtype=float)
        y = target.loc[m["stimulus"], "dmos"].to_numpy(dtype=float)
        mapping = fit_mapping(q, y)
        pred = mapping(q)
        mappings[name] = mapping
        methods = target.loc[m["stimulus"], "method"].to_numpy()
        data[name] = pd.DataFrame({"stimulus": m["stimulus"].to_numpy(), "score": q, "dmos": y,
                                   "predicted": pred, "method": methods,
                                   "scene": target.loc[m["stimulus"], "scene"].to_numpy()})
        point = all_columns(y, pred)
        raw = all_columns(y, q)
        point["srcc"], point["krcc"] = raw["srcc"], raw["krcc"]
        idx = rng.integers(0, len(y), size=(n_boot, len(y)))
        boot = _bootstrap(y, pred, q, idx)
        boots[name] = (m["stimulus"].to_numpy(), boot)
        row = {"metric": name, "n": len(y), "fit": mapping.kind}
        for key in STATS:
            row[key] = float(point[key][0])
            row[f"{key}_ci95_low"], row[f"{key}_ci95_high"] = percentile_interval(boot[key])
        row["backbone"] = scores.untrained().get(name, "")
        rows.append(row)
        for method in dict.fromkeys(methods):
            sel = methods == method
            if sel.sum() >= 3:
                method_rows.append({
                    "metric": name, "method": method, "n": int(sel.sum()),
                    "plcc": float(pearson_columns(y[sel], pred[sel])[0]),
                    "srcc": float(all_columns(y[sel], q[sel])["srcc"][0]),
                })
    if not rows:
        raise AnalysisError("no metric could be compared with DMOS (no shared stimuli); check "
                            "that the score CSV's stimulus ids match the manifest")
    table = pd.DataFrame(rows)
    if ceiling:
        human = {"metric": "human ceiling (split-half)", "n": len(target), "fit": "none",
                 "backbone": ""}
        for key in STATS:
            c = ceiling.get(key, {})
            human[key] = c.get("median", np.nan)
            human[f"{key}_ci95_low"] = c.get("ci95_low", np.nan)
            human[f"{key}_ci95_high"] = c.get("ci95_high", np.nan)
        table = pd.concat([table, pd.DataFrame([human])], ignore_index=True)

    names = list(mappings)
    pvals = pd.DataFrame(np.nan, index=names, columns=names)
    for a, b in itertools.permutations(names, 2):
        pvals.loc[a, b] = _paired_p(data[a], data[b], mappings[a], mappings[b], n_boot,
                                    seed)
    better = pvals < alpha
    return MetricValidation(table, pd.DataFrame(method_rows), pvals, better, mappings, data,
                            problems, scores.untrained(), alpha)


def _paired_p(da: pd.DataFrame, db: pd.DataFrame, ma: Mapping, mb: Mapping,
              n_boot: int, seed: int) -> float:
    """One-tailed paired bootstrap p-value of H0: PLCC(a) <= PLCC(b) on shared stimuli."""
    shared = da.merge(db, on="stimulus", suffixes=("_a", "_b"))
    if len(shared) < 3:
        return float("nan")
    y = shared["dmos_a"].to_numpy()
    pa, pb = ma(shared["score_a"].to_numpy()), mb(shared["score_b"].to_numpy())
    idx = np.random.default_rng(seed + 1).integers(0, len(y), size=(n_boot, len(y)))
    ra = pearson_columns(y[idx].T, pa[idx].T)
    rb = pearson_columns(y[idx].T, pb[idx].T)
    diff = ra - rb
    diff = diff[np.isfinite(diff)]
    return float(np.mean(diff <= 0)) if diff.size else float("nan")
