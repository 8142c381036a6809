"""Metric versus humans, as ITU-T P.1401 does it, for every metric in the scores files.

The scores come oriented (higher means better quality) from :mod:`analysis.metric_scores`,
which reads the ``cgvq-scores/1`` files. Metrics computed with a random backbone or uniform
weights stay flagged wherever they appear.

Per metric: the 5-parameter logistic mapping (:mod:`analysis.mapping`), PLCC and P.1401's rmse
(``N - d``) on mapped scores, SRCC and KRCC on the oriented scores, the epsilon-insensitive
rmse* and the outlier ratio from the DMOS CIs; all overall and per distortion method.

Intervals: a two-way bootstrap. Each resample takes a resample of the raters (the DMOS of
:mod:`analysis.intervals`) and a resample of the stimuli, stratified by distortion method, and
refits the mapping inside the resample. Rating noise attenuates correlations and the in-sample
fit flatters them; the bootstrap reproduces both, so the interval is the bias-corrected
percentile interval on Fisher's z (log for rmse), its bias taken against the bootstrap world's
own value, its spread widened by the small-sample correction of :func:`small_sample_factor`
(coverage checked in ``benchmarks/bench_coverage.py``; see :func:`_interval`).
Significance: the paper's one-tailed paired bootstrap test of PLCC, Williams'
t and Steiger's Z for dependent correlations, and P.1401's F-test on rmse and rmse*.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from stimuli_manifests.tables import DIRECTIONS

from .data import InputProblem
from .errors import AnalysisError
from .mapping import N_PARAMS, Mapping, fit_mapping, logistic5, refit_batch
from .metric_scores import MetricScores, load_metric_scores, metric_id
from .p1401 import (
    dependent_correlation_tests,
    outlier_ratio,
    rmse_dof,
    rmse_f_test,
    rmse_star,
)
from .stats import kendall_columns, pearson_columns, spearman_columns

log = logging.getLogger(__name__)

__all__ = ["Mapping", "MetricScores", "MetricValidation", "fit_mapping", "load_metric_scores",
           "logistic5", "metric_id", "validate_metrics"]

STATS = ("plcc", "srcc", "krcc", "rmse")
HIGHER, LOWER = DIRECTIONS
CEILING_ROW = "two half panels (split-half agreement)"
"""The metric table's last row when the ceiling was computed: the humans as a 'metric'."""


# -- resampling ------------------------------------------------------------------------------
#: the fewest stimuli a distortion method needs to be a bootstrap stratum of its own. A
#: stratum of one stimulus adds no resampling variability at all (it is the same in every
#: resample) and one of two only half its variance, from 4 distinct draws; when every method
#: is that small the stratified bootstrap collapses (zero-width CIs, a paired test p of 0 or
#: 1). From 3 on a stratum keeps (m - 1) / m >= 2/3 of its variance, a loss that
#: :func:`small_sample_factor` corrects, and 3 is also the fewest stimuli a per-method
#: statistic is reported for, so every method that gets its own row keeps its own block.
MIN_STRATUM = 3

#: the block of the stimuli of methods smaller than :data:`MIN_STRATUM`, resampled together
#: (no method is named so: it starts with a character no manifest id holds)
POOLED = "\x00pooled"


def strata(groups: np.ndarray, min_size: int = MIN_STRATUM) -> np.ndarray:
    """The bootstrap stratum of every stimulus: its method, or :data:`POOLED` for methods with
    fewer than ``min_size`` stimuli. A pool that is itself small (one method of 1-2 stimuli
    beside large ones) stays a stratum: the large methods keep their per-method blocks, and
    :func:`small_sample_factor`, counting the pool as a stratum, makes up for its variance."""
    groups = np.asarray(groups).astype(str)
    labels, counts = np.unique(groups, return_counts=True)
    small = labels[counts < min_size]
    return np.where(np.isin(groups, small), POOLED, groups) if small.size else groups


def stratified_indices(groups: np.ndarray, n_boot: int, rng: np.random.Generator, *,
                       min_size: int = MIN_STRATUM) -> tuple[np.ndarray, dict[str, slice]]:
    """Bootstrap indices (B, n) drawn within each stratum of :func:`strata`; columns are
    grouped in blocks, one per stratum, keyed by method (:data:`POOLED` for the pool)."""
    groups = strata(groups, min_size)
    blocks, parts, start = {}, [], 0
    for g in dict.fromkeys(groups):
        members = np.flatnonzero(groups == g)
        parts.append(members[rng.integers(0, members.size, size=(n_boot, members.size))])
        blocks[str(g)] = slice(start, start + members.size)
        start += members.size
    return np.concatenate(parts, axis=1), blocks


def resamples_vary(blocks: dict[str, slice]) -> bool:
    """Whether stimulus resamples can differ from the data: some stratum holds 2 or more."""
    return any(b.stop - b.start >= 2 for b in blocks.values())


def small_sample_factor(n: int, strata: int) -> float:
    """How much wider than the bootstrap spread an interval of a statistic of ``n`` stimuli
    resampled within ``strata`` groups must be: the within-group bootstrap variance is
    ``(n - strata) / n`` of the sampling variance, and the 97.5% quantile is Student's with
    n - 3 degrees of freedom (Fisher's z of a correlation) rather than the normal one.
    NaN when every stratum holds one stimulus: the resamples carry no information about the
    sampling of stimuli, so no interval can be given (not a zero-width one)."""
    if n - strata < 1:
        return float("nan")
    if n <= 3:
        return 1.0
    return float(np.sqrt(n / (n - strata)) * stats.t.ppf(0.975, n - 3) / stats.norm.ppf(0.975))


CORR_CLIP = 0.999999
"""Correlations are clipped here before Fisher's z; resamples at the clip carry no spread."""

MIN_INTERVAL_STIMULI = 6
"""Fewer stimuli (in one distortion method) give no interval: Student's quantile with
n - 3 <= 2 degrees of freedom widens it past any use (an rmse interval of [0.4, 1199])."""


def _interval(point: float, ref: float, boot: np.ndarray, kind: str, *,
              factor: float = 1.0) -> tuple[float, float]:
    """Bias-corrected percentile interval on Fisher's z (correlations) or log (rmse):
    ``point - bias - factor * (median - q2.5)`` to ``point - bias + factor * (q97.5 -
    median)``, with ``bias`` = median of the resamples minus ``ref`` (the statistic of the
    bootstrap world: the full data under the estimator the resamples use), the quantiles
    those of the resamples, and ``factor`` the small-sample correction of
    :func:`small_sample_factor`.

    The basic interval (the spreads reversed) was used before. With few stimuli a refitted
    logistic overfits resamples that repeat stimuli, their PLCCs crowd towards 1, and z
    stretches that tail; reversed, it became a lower bound far below every resample (PLCC
    0.918 with [0.13, 0.97] while the resamples' 95% lay in [0.84, 0.99]). In the coverage
    benchmark's simulated studies (12 raters x 2 repetitions, 400 studies of 16 conditions)
    the basic interval covered 0.993 and 0.965 of the two metrics' true PLCCs, this one 0.975
    and 0.950 (and the true RMSE: 0.925 and 0.907, against 0.983 and 0.960); with 32 and 72
    conditions both cover 0.94-0.95, this one a little narrower
    (``benchmarks/bench_interval_orientation.py``)."""
    boot = boot[np.isfinite(boot)]
    if boot.size < 10 or not np.isfinite(point) or not np.isfinite(ref) or \
            not np.isfinite(factor):
        return float("nan"), float("nan")
    if kind == "corr":
        fwd, inv = (lambda x: np.arctanh(np.clip(x, -CORR_CLIP, CORR_CLIP))), np.tanh
        degenerate = np.abs(boot) >= CORR_CLIP  # |r| = 1: z is infinite
    else:
        fwd, inv = (lambda x: np.log(np.maximum(x, 1e-12))), np.exp
        degenerate = boot <= 1e-12  # rmse 0: log is -infinite
    if degenerate.mean() > 0.025:
        # A tail of resamples at the scale's end (a few stimuli, all in order) has no spread
        # on z: the interval would be set by the clip ([-1, 0.998], or zero width).
        return float("nan"), float("nan")
    lo_q, mid, hi_q = np.percentile(fwd(boot), [2.5, 50.0, 97.5])
    centre = fwd(np.array(point)) - (mid - fwd(np.array(ref)))
    return (float(inv(centre - factor * (mid - lo_q))),
            float(inv(centre + factor * (hi_q - mid))))


def _point_stats(y: np.ndarray, q: np.ndarray, pred: np.ndarray, d: int) -> dict[str, float]:
    return {"plcc": float(pearson_columns(y, pred)[0]),
            "srcc": float(spearman_columns(y, q)[0]),
            "krcc": float(kendall_columns(y, q)[0]),
            "rmse": rmse_dof(y, pred, d)}


def _boot_stats(yb: np.ndarray, qb: np.ndarray, pb: np.ndarray,
                d: int | np.ndarray) -> dict[str, np.ndarray]:
    """Statistics of every resample (rows of (B, n) arrays); ``d``, the mapping's parameter
    count for P.1401's rmse, per row where some resamples fell back to the line."""
    n = yb.shape[1]
    err = ((yb - pb) ** 2).sum(axis=1)
    dof = n - np.broadcast_to(np.asarray(d, dtype=float), err.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        rmse = np.where(dof > 0, np.sqrt(err / np.where(dof > 0, dof, 1.0)), np.nan)
    return {"plcc": pearson_columns(yb.T, pb.T), "srcc": spearman_columns(yb.T, qb.T),
            "krcc": kendall_columns(yb.T, qb.T), "rmse": rmse}


def resample_params(mapping: Mapping, kept: np.ndarray) -> np.ndarray:
    """Per resample, the parameters its refit used: the mapping's, or the line's (2) where
    the refit fell back to it (P.1401's rmse divides by N - d of the fit actually made)."""
    return np.where(kept, mapping.n_params, N_PARAMS["linear (fallback)"])


# -- validation ----------------------------------------------------------------------------
@dataclass
class MetricValidation:
    """Everything the report shows about metrics against DMOS."""

    table: pd.DataFrame  # one row per metric (+ the human ceiling row)
    per_method: pd.DataFrame
    significance: pd.DataFrame  # bootstrap p-value that row metric's PLCC > column metric's
    better: pd.DataFrame  # bool: row significantly better than column at alpha
    mappings: dict[str, Mapping]
    data: dict[str, pd.DataFrame]  # per metric: stimulus, score, dmos, predicted, method
    problems: list[InputProblem]
    untrained: dict[str, str]
    alpha: float
    comparisons: pd.DataFrame = field(default_factory=pd.DataFrame)  # all pairwise tests
    williams: pd.DataFrame = field(default_factory=pd.DataFrame)  # Williams' p matrix
    boot: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    boot_ref: dict[str, dict[str, float]] = field(default_factory=dict)  # bootstrap world
    not_applicable: dict[str, str] = field(default_factory=dict)  # metric -> why no score
    ppd: dict[str, float] = field(default_factory=dict)  # metric -> its pixels per degree
    provenance: dict[str, dict[str, list[Any]]] = field(default_factory=dict)  # see MetricScores
    titles: dict[str, str] = field(default_factory=dict)  # metric -> the name prose prints
    #: metric -> why its numbers cannot be read as declared (:func:`direction_doubt`)
    suspect: dict[str, str] = field(default_factory=dict)

    def title(self, metric: str) -> str:
        """The name prose and figures print for ``metric`` (its id when it has no title)."""
        return self.titles.get(metric, metric)


@dataclass
class _Fitted:
    name: str
    rows: np.ndarray  # positions in the target table
    q: np.ndarray
    y: np.ndarray
    mapping: Mapping
    pred: np.ndarray
    idx: np.ndarray
    blocks: dict[str, slice]
    boot: dict[str, np.ndarray]
    pred_boot: np.ndarray
    y_boot: np.ndarray


def validate_metrics(
    dmos: pd.DataFrame,
    scores: MetricScores,
    *,
    boot=None,
    n_boot: int = 1000,
    seed: int = 0,
    alpha: float = 0.05,
    ceiling: dict[str, dict[str, float]] | None = None,
) -> MetricValidation:
    """Compare every metric with DMOS (hidden references excluded: their DMOS is fixed).

    Long on purpose: the per-metric fits, the shared bootstrap draws and the comparisons
    between metrics must use the same resamples in the same order (seeded), which one body
    keeps visible.

    ``dmos`` is :func:`analysis.scores.dmos_table`'s frame; ``boot`` the
    :class:`~analysis.intervals.RaterBootstrap` of the same rating set (rows in the same
    order). Without it only the stimuli are resampled (DMOS held fixed).
    """
    hidden = dmos["is_hidden_reference"].astype(bool).to_numpy()
    finite = np.isfinite(pd.to_numeric(dmos["dmos"], errors="coerce").to_numpy(dtype=float))
    problems = list(scores.problems) + no_dmos_problems(dmos, ~hidden & ~finite)
    use = ~hidden & finite
    target = dmos[use].reset_index(drop=True)
    positions = np.flatnonzero(use)
    y_all = target["dmos"].to_numpy(dtype=float)
    ci_all = ((target["ci95_high"] - target["ci95_low"]) / 2).to_numpy(dtype=float)
    methods_all = target["method"].astype(str).to_numpy()
    if boot is not None:
        n_boot = boot.dmos.shape[1]
        yb_all = boot.dmos[positions].T  # (B, T)
        y_ref_all = boot.dmos_full[positions]
    else:
        yb_all = np.tile(y_all, (n_boot, 1))
        y_ref_all = y_all
    sid = pd.Index(target["stimulus"].astype(str))
    # One set of stimulus draws shared by every metric that covers all stimuli, so paired
    # comparisons pair the same resamples.
    shared_idx = stratified_indices(methods_all, n_boot, np.random.default_rng([seed, 23]))
    fitted: dict[str, _Fitted] = {}
    refs: dict[str, dict[str, float]] = {}
    rows, method_rows = [], []
    skipped: list[str] = []  # why a metric was not evaluated, for the error when none was
    suspect: dict[str, str] = {}  # metric -> why its numbers cannot be read as declared
    study_ids = dmos["stimulus"].astype(str)
    by_case = {s.casefold(): s for s in study_ids}
    reference_of = dict(zip(study_ids, dmos["reference"].astype(str), strict=True))
    references = set(reference_of.values())
    for name in scores.metrics:
        m = scores.frame[scores.frame["metric"] == name]
        known = m["stimulus"].isin(study_ids)
        for _, row in m[~known].iterrows():
            near = by_case.get(str(row["stimulus"]).casefold())
            hint = f" (the study has {near!r}: ids are case-sensitive)" if near else ""
            problems.append(InputProblem(row["_source"], int(row["_row"]),
                                         f"{name}: stimulus {row['stimulus']!r} is not one of "
                                         f"the study's rated stimuli{hint}; left out"))
        contradicts = known & _other_reference(m, reference_of, references)
        for _, row in m[contradicts].iterrows():
            problems.append(InputProblem(row["_source"], int(row["_row"]), (
                f"{name}: {row['stimulus']} scored against reference {row['reference']}, but "
                f"its reference in the manifest is {reference_of[row['stimulus']]}; left out")))
        m = m[m["stimulus"].isin(sid) & ~contradicts]
        if len(m) < 3:
            why = (f"no stimulus id of its {int(known.size)} score row(s) is in the DMOS table "
                   "(no shared stimuli)" if not known.any() else
                   f"only {len(m)} stimul{'us' if len(m) == 1 else 'i'} shared with the DMOS "
                   "table (hidden references aside); a correlation needs at least 3")
            problems.append(InputProblem(name, None, f"{why}; metric not evaluated"))
            skipped.append(f"{name}: {why}")
            continue
        if len(m) < len(sid):  # ranked against metrics that saw every stimulus: say so
            missing = sorted(set(sid) - set(m["stimulus"].astype(str)))
            problems.append(InputProblem(name, None, (
                f"{len(missing)} of {len(sid)} stimuli have no score ("
                + ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
                + f"); its statistics are on the other {len(m)} only")))
        pos = sid.get_indexer(m["stimulus"].astype(str))
        order = np.argsort(pos)
        pos = pos[order]
        draws = shared_idx if len(pos) == len(sid) else stratified_indices(
            methods_all[pos], n_boot, np.random.default_rng([seed, 23, len(pos),
                                                             int(pos.sum())]))
        f = _fit_one(name, pos, m["oriented"].to_numpy(dtype=float)[order], y_all, yb_all,
                     draws)
        fitted[name] = f
        d = f.mapping.n_params
        ci = ci_all[pos]
        point = _point_stats(f.y, f.q, f.pred, d)
        ref = _ref_stats(f, y_ref_all[pos], d)
        refs[name] = ref
        row = {"metric": name, "direction": scores.direction(name), "n": len(f.y),
               "fit": f.mapping.kind, "d": d}
        for key in STATS:
            row[key] = point[key]
            row[f"{key}_ci95_low"], row[f"{key}_ci95_high"] = _interval(
                point[key], ref[key], f.boot[key], "rmse" if key == "rmse" else "corr",
                factor=small_sample_factor(len(f.y), len(f.blocks)))
        row["rmse_star"] = rmse_star(f.y, f.pred, ci, d)
        row["outlier_ratio"] = outlier_ratio(f.y, f.pred, ci)
        row["flag"] = scores.flags.get(name, "")
        rows.append(row)
        doubt = direction_doubt(scores.direction(name), point["srcc"], f.q)
        if doubt:
            suspect[name] = doubt
            problems.append(InputProblem(name, None, doubt))
        method_rows += _per_method(f, ci, y_ref_all[pos], methods_all[pos])
    if not rows:
        raise AnalysisError(_nothing_compared(skipped, scores.not_applicable))
    table = pd.DataFrame(rows)
    if ceiling:
        human = {"metric": CEILING_ROW, "direction": "", "n": len(target),
                 "fit": "none", "d": 0, "flag": ""}
        for key in STATS:
            c = ceiling.get(key, {})
            human[key] = c.get("median", np.nan)
            # the splits' 2.5-97.5 percentiles, in the columns other rows fill with CIs
            human[f"{key}_ci95_low"] = c.get("p2_5", np.nan)
            human[f"{key}_ci95_high"] = c.get("p97_5", np.nan)
        table = pd.concat([table, pd.DataFrame([human])], ignore_index=True)
    comparisons = _comparisons(fitted, y_all, yb_all, ci_all, methods_all, n_boot, seed)
    names = list(fitted)
    overall = comparisons[comparisons["scope"] == "all"] if len(comparisons) else comparisons
    pvals = pd.DataFrame(np.nan, index=names, columns=names)
    williams = pd.DataFrame(np.nan, index=names, columns=names)
    for _, c in overall.iterrows():
        pvals.loc[c["metric_a"], c["metric_b"]] = c["boot_p"]
        williams.loc[c["metric_a"], c["metric_b"]] = c["williams_p"]
    data = {name: pd.DataFrame({
        "stimulus": target["stimulus"].to_numpy()[f.rows],
        "score": scores.frame.set_index(["metric", "stimulus"]).loc[name]["score"]
        .reindex(target["stimulus"].to_numpy()[f.rows]).to_numpy(),
        "oriented": f.q, "dmos": f.y, "predicted": f.pred,
        "method": methods_all[f.rows], "scene": target["scene"].to_numpy()[f.rows]})
        for name, f in fitted.items()}
    return MetricValidation(table, pd.DataFrame(method_rows), pvals, pvals < alpha,
                            {n: f.mapping for n, f in fitted.items()}, data, problems,
                            dict(scores.flags), alpha, comparisons, williams,
                            {n: f.boot for n, f in fitted.items()}, refs,
                            dict(scores.not_applicable), dict(scores.ppd),
                            {n: scores.provenance[n] for n in fitted if n in scores.provenance},
                            dict(scores.titles), suspect)


def _other_reference(rows: pd.DataFrame, reference_of: dict[str, str],
                     references: set[str]) -> pd.Series:
    """Rows whose ``reference`` is another of the study's references than the manifest gives
    their stimulus (a scene mix-up). A name that is no reference id of the study (a file
    stem, as ``score --csv`` writes it) says nothing either way and is not held against it."""
    if "reference" not in rows.columns:
        return pd.Series(False, index=rows.index)
    given = rows["reference"].astype(str)
    expected = rows["stimulus"].astype(str).map(reference_of)
    return given.isin(references) & expected.notna() & (given != expected)


def direction_doubt(direction: str, srcc: float, oriented: np.ndarray) -> str:
    """Why a metric's statistics cannot be read as it was declared ("" when they can): its
    oriented scores fall as DMOS rises (its ``direction`` is likely the wrong way round; the
    mapping, monotone in the data's own trend, would still give a positive PLCC), or it
    gives every stimulus one score (no correlation is defined)."""
    if np.ptp(oriented) == 0:
        score = -oriented[0] if direction == LOWER else oriented[0]
        return f"it gives every stimulus the same score ({score:g}); no correlation is defined"
    if np.isfinite(srcc) and srcc < 0:
        other = HIGHER if direction == LOWER else LOWER
        return (f"its scores fall as DMOS rises (SRCC {srcc:.3f} with the declared direction "
                f"{direction}): is it {other}? Its positive PLCC comes from a mapping that "
                "falls with the score; fix the direction column and run again")
    return ""


def no_dmos_problems(dmos: pd.DataFrame, bad: np.ndarray) -> list[InputProblem]:
    """The stimuli whose DMOS is not a number (no rating left, a model gap): they are left out
    of every metric statistic, which one NaN would otherwise turn into NaN; said, never
    silent."""
    if not bad.any():
        return []
    ids = dmos["stimulus"].astype(str).to_numpy()[bad].tolist()
    msg = (f"{len(ids)} stimul{'us' if len(ids) == 1 else 'i'} without a finite DMOS left out "
           f"of the metric statistics: {', '.join(ids)}")
    log.warning(msg)
    return [InputProblem("DMOS", None, msg)]


def _nothing_compared(skipped: list[str], not_applicable: dict[str, str]) -> str:
    """The error when no metric could be compared with DMOS, saying why for each metric."""
    why = skipped + [f"{m}: does not apply ({n})" for m, n in not_applicable.items()]
    if not why:
        return "no metric could be compared with DMOS: the score CSVs hold no usable score row"
    advice = [text for found, text in (
        (any("no shared stimuli" in w for w in skipped),
         "check that the score CSV's stimulus ids match the manifest"),
        (any("a correlation needs" in w for w in skipped),
         "score at least 3 of the rated stimuli"),
        (not skipped, "score stimuli the metric applies to")) if found]
    return "no metric could be compared with DMOS: " + "; ".join(why[:3]) + \
        (f"; ... and {len(why) - 3} more" if len(why) > 3 else "") + "; " + "; ".join(advice)


def _fit_one(name: str, pos: np.ndarray, q: np.ndarray, y_all: np.ndarray,
             yb_all: np.ndarray, draws: tuple[np.ndarray, dict[str, slice]]) -> _Fitted:
    y = y_all[pos]
    mapping = fit_mapping(q, y)
    pred = mapping(q)
    idx, blocks = draws
    rows_b = np.arange(idx.shape[0])[:, None]
    yb = yb_all[:, pos][rows_b, idx]
    qb = q[idx]
    pb, kept = refit_batch(mapping, qb, yb)
    boot = _boot_stats(yb, qb, pb, resample_params(mapping, kept))
    return _Fitted(name, pos, q, y, mapping, pred, idx, blocks, boot, pb, yb)


def _ref_stats(f: _Fitted, y_ref: np.ndarray, d: int) -> dict[str, float]:
    """The statistics in the bootstrap world: full stimuli, full-panel DMOS of the fast
    estimator, mapping refitted on it."""
    pred, _ = refit_batch(f.mapping, f.q[None, :], y_ref[None, :])
    return _point_stats(y_ref, f.q, pred[0], d)


def _per_method(f: _Fitted, ci: np.ndarray, y_ref: np.ndarray,
                methods: np.ndarray) -> list[dict]:
    out = []
    pred_ref, _ = refit_batch(f.mapping, f.q[None, :], y_ref[None, :])
    for method, block in f.blocks.items():
        sel = methods == method
        if sel.sum() < 3:
            continue
        row = {"metric": f.name, "method": method, "n": int(sel.sum())}
        point = _point_stats(f.y[sel], f.q[sel], f.pred[sel], 0)
        ref = _point_stats(y_ref[sel], f.q[sel], pred_ref[0][sel], 0)
        boot = _boot_stats(f.y_boot[:, block], f.q[f.idx[:, block]], f.pred_boot[:, block], 0)
        for key in STATS:
            row[key] = point[key]
            row[f"{key}_ci95_low"], row[f"{key}_ci95_high"] = _interval(
                point[key], ref[key], boot[key], "rmse" if key == "rmse" else "corr",
                factor=small_sample_factor(int(sel.sum()), 1)
                if sel.sum() >= MIN_INTERVAL_STIMULI else float("nan"))
        row["rmse_star"] = rmse_star(f.y[sel], f.pred[sel], ci[sel], 0)
        row["outlier_ratio"] = outlier_ratio(f.y[sel], f.pred[sel], ci[sel])
        out.append(row)
    return out


def _comparisons(fitted: dict[str, _Fitted], y_all: np.ndarray, yb_all: np.ndarray,
                 ci_all: np.ndarray, methods_all: np.ndarray, n_boot: int,
                 seed: int) -> pd.DataFrame:
    """Every ordered pair of metrics, overall and per method: is a better than b?"""
    rows = []
    for a, b in itertools.permutations(fitted, 2):
        fa, fb = fitted[a], fitted[b]
        shared = np.intersect1d(fa.rows, fb.rows)
        if shared.size < 4:
            continue
        same = np.array_equal(fa.rows, fb.rows)
        if same:
            pa_b, pb_b, ya_b = fa.pred_boot, fb.pred_boot, fa.y_boot
            idx, blocks = fa.idx, fa.blocks
            pa, pb = fa.pred, fb.pred
        else:  # different stimulus sets: refit both on the shared stimuli
            ia, ib = np.searchsorted(fa.rows, shared), np.searchsorted(fb.rows, shared)
            ma, mb = fit_mapping(fa.q[ia], y_all[shared]), fit_mapping(fb.q[ib], y_all[shared])
            pa, pb = ma(fa.q[ia]), mb(fb.q[ib])
            rng = np.random.default_rng([seed, 29, len(shared), int(shared.sum())])
            idx, blocks = stratified_indices(methods_all[shared], n_boot, rng)
            ya_b = yb_all[:, shared][np.arange(n_boot)[:, None], idx]
            pa_b, _ = refit_batch(ma, fa.q[ia][idx], ya_b)
            pb_b, _ = refit_batch(mb, fb.q[ib][idx], ya_b)
        order = fa.rows if same else shared
        y = y_all[order]
        ci = ci_all[order]
        methods = methods_all[order]
        da = fa.mapping.n_params
        db = fb.mapping.n_params
        scopes = [("all", np.ones(len(order), dtype=bool), slice(None))]
        scopes += [(m, methods == m, blk) for m, blk in blocks.items()]
        for scope, sel, blk in scopes:
            if sel.sum() < 4:
                continue
            dda, ddb = (da, db) if scope == "all" else (0, 0)
            ra = pearson_columns(ya_b[:, blk].T, pa_b[:, blk].T)
            rb = pearson_columns(ya_b[:, blk].T, pb_b[:, blk].T)
            diff = (ra - rb)[np.isfinite(ra - rb)]
            tests = dependent_correlation_tests(y[sel], pa[sel], pb[sel])
            rmse_a, rmse_b = rmse_dof(y[sel], pa[sel], dda), rmse_dof(y[sel], pb[sel], ddb)
            f_rmse, p_rmse = rmse_f_test(rmse_b, int(sel.sum()), ddb, rmse_a, int(sel.sum()),
                                         dda)
            star_a = rmse_star(y[sel], pa[sel], ci[sel], dda)
            star_b = rmse_star(y[sel], pb[sel], ci[sel], ddb)
            f_star, p_star = rmse_f_test(star_b, int(sel.sum()), ddb, star_a, int(sel.sum()),
                                         dda)
            rows.append({
                "scope": scope, "metric_a": a, "metric_b": b, "n": int(sel.sum()),
                "plcc_a": float(pearson_columns(y[sel], pa[sel])[0]),
                "plcc_b": float(pearson_columns(y[sel], pb[sel])[0]),
                "boot_p": float((np.sum(diff <= 0) + 1) / (diff.size + 1))
                if diff.size and resamples_vary(
                    {scope: blk} if scope != "all" else blocks) else float("nan"),
                "boot_n": int(diff.size),  # resamples where both correlations exist
                **tests,
                "rmse_F": f_rmse, "rmse_p": p_rmse, "rmse_star_F": f_star,
                "rmse_star_p": p_star,
            })
    return pd.DataFrame(rows)
