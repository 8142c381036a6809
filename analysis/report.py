"""The report folder: report.html, figures/*.png, dmos.csv, tables as CSV, summary.json.

The first screen of report.html says what went into the numbers and what did not: sessions
refused (another study, another manifest, withdrawn), copies of sessions, partial sessions
dropped or kept, raters removed by the screening and why, a model fallback, and metric scores
that do not come from the published metric.
"""

from __future__ import annotations

import html
import json
import logging
import math
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from . import __version__
from .exports import write_dmos_csv, write_rating_matrix
from .figures import draw_all
from .pipeline import Analysis
from .quality import THRESHOLDS
from .sureal_io import write_sureal_json

log = logging.getLogger(__name__)

SUMMARY_FORMAT = "cgvq-analysis-summary/2"

_QUALITY_COLUMNS = ("status", "sessions", "n_ratings", "n_planned", "completeness",
                    "timing_mode", "vsync", "preflight_skipped", "presentations",
                    "dropped_frames", "trials_with_drops", "requeued", "median_viewing_s",
                    "median_toggles", "hidden_ref_mean_share", "loo_r", "repeat_r", "flags")


def _num(x: Any) -> Any:
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if x is pd.NA or x is pd.NaT:
        return None
    return x


def _records(frame: pd.DataFrame | None, *, index: str | None = None) -> list[dict[str, Any]]:
    if frame is None or frame.empty:
        return []
    f = frame.reset_index() if index else frame
    return [{k: _num(v) for k, v in row.items()} for row in f.to_dict("records")]


def summary(a: Analysis) -> dict[str, Any]:
    """Machine-readable results (the demo and scripts read ``summary.json``)."""
    rs, sc = a.screened, a.scores
    used = a.used or rs
    out: dict[str, Any] = {
        "format": SUMMARY_FORMAT,
        "study": rs.study,
        "source": a.ratings.source,
        "model": sc.model,
        "model_name": sc.model_name,
        "model_fallback": sc.fallback,
        "outlier_method": a.outliers.method,
        "min_completeness": a.config.min_completeness,
        "alpha": a.config.alpha,
        "seed": a.config.seed,
        "n_bootstrap": a.config.n_boot,
        "n_splits": a.config.n_splits,
        "n_raters_input": a.ratings.n_raters,
        "n_raters_after_completeness": used.n_raters,
        "n_raters_used": rs.n_raters,
        "n_stimuli": rs.n_stimuli,
        "n_ratings_used": rs.n_ratings,
        "exclusions": [x.__dict__ for x in a.exclusions],
        "partial_kept": [{"rater": r, "completeness": c} for r, c in a.partial_kept],
        "removed_raters": [
            {"rater": r.rater, "method": r.method, "statistic": _num(r.statistic),
             "critical": _num(r.critical), "value": _num(r.value), "reason": r.reason}
            for r in a.outliers.removed
        ],
        "screening": _records(a.outliers.table, index="rater"),
        "model_rejected_raters": list(sc.rejected),
        "data_quality": _records(a.quality.reindex(columns=list(_QUALITY_COLUMNS))
                                 if a.quality is not None else None, index="rater"),
        "flag_thresholds": THRESHOLDS,
        "n_input_problems": len(a.problems),
        "timings_s": {k: round(v, 3) for k, v in a.timings.items()},
    }
    if a.reliability is not None:
        rel = a.reliability
        out["icc"] = {k: _num(v) for k, v in rel.icc.items()}
        out["icc_ci95"] = {k: [_num(v[0]), _num(v[1])] for k, v in rel.icc_ci.items()}
        out["icc_method"] = rel.method
        out["icc_counts"] = {"stimuli": rel.n_stimuli, "raters": rel.n_raters,
                             "cells": rel.n_cells, "complete_stimuli": rel.n_targets}
        if rel.complete_case:
            out["icc_complete_case"] = {
                "n_stimuli": rel.complete_case["n_stimuli"],
                "icc": {k: _num(v) for k, v in rel.complete_case["icc"].items()}}
        out["intra_rater_mean_r"] = _num(rel.intra_rater.mean())
    if a.ceiling is not None:
        out["ceiling"] = {k: {kk: _num(vv) for kk, vv in v.items()}
                          for k, v in a.ceiling.summary().items()}
        out["ceiling_stimuli"] = {"distorted": a.ceiling.n_stimuli,
                                  "median_used_per_split": _num(a.ceiling.median_used)}
    if a.ci_curve is not None:
        c = a.ci_curve
        red = c.reduction_per_rater()
        out["ci_curve"] = {
            "power_law_a": _num(c.a), "power_law_b": _num(c.b),
            "dmos_width": None if c.dmos_width is None else [_num(w) for w in c.dmos_width],
            "n_raters": [int(n) for n in c.n_raters],
            "reduction_per_added_rater": {str(k): _num(v) for k, v in red.items()},
            "reduction_decay_rate": _num(c.decay_rate),
            "reduction_power": _num(c.reduction_power)}
    if a.metrics is not None:
        m = a.metrics
        out["metrics"] = _records(m.table)
        out["metrics_per_method"] = _records(m.per_method)
        out["untrained_backbone"] = dict(m.untrained)
        out["not_applicable"] = dict(m.not_applicable)
        out["significance_p"] = {
            r: {c: _num(m.significance.loc[r, c]) for c in m.significance.columns}
            for r in m.significance.index}
        out["williams_p"] = {
            r: {c: _num(m.williams.loc[r, c]) for c in m.williams.columns}
            for r in m.williams.index}
    return out


def summary_text(a: Analysis) -> str:
    """A short terminal summary."""
    s = summary(a)
    lines = [f"study {s['study']}: {s['n_stimuli']} stimuli, {s['n_raters_used']} of "
             f"{s['n_raters_input']} raters, {s['n_ratings_used']} ratings; model "
             f"{s['model_name']}"]
    if s["model_fallback"]:
        lines.append(f"WARNING: {s['model_fallback']}")
    refused = [x for x in s["exclusions"] if x["kind"] in ("refused session",
                                                           "duplicate session")]
    if refused:
        lines.append(f"sessions not used: {len(refused)} ("
                     + ", ".join(f"{Path(x['who']).name}: {x['kind']}" for x in refused[:6])
                     + (", ..." if len(refused) > 6 else "") + ")")
    partial = [x for x in s["exclusions"] if x["kind"] == "partial rater"]
    if partial:
        lines.append(f"partial raters left out (--min-completeness {s['min_completeness']:g}): "
                     + ", ".join(x["who"] for x in partial))
    if s["partial_kept"]:
        lines.append("partial raters kept: " + ", ".join(
            f"{p['rater']} ({p['completeness']:.0%})" for p in s["partial_kept"]))
    lines.append(f"removed raters ({s['outlier_method']}): "
                 + (", ".join(r["rater"] for r in s["removed_raters"]) or "none"))
    if "icc" in s:
        lines.append(f"ICC(2,k) {s['icc']['ICC(2,k)']:.3f}   ICC(3,k) {s['icc']['ICC(3,k)']:.3f}"
                     + ("   (REML, unbalanced)" if "REML" in s["icc_method"] else ""))
    if "ceiling" in s:
        c = s["ceiling"]["plcc"]
        lines.append(f"human ceiling (split-half PLCC) {c['median']:.3f} "
                     f"[{c['ci95_low']:.3f}, {c['ci95_high']:.3f}]")
    if "metrics" in s:
        lines.append(f"{'metric':32s} {'n':>4s} {'PLCC':>7s} {'SRCC':>7s} {'KRCC':>7s} "
                     f"{'RMSE':>8s} {'RMSE*':>8s}")
        for m in s["metrics"]:
            vals = [m.get(k) for k in ("plcc", "srcc", "krcc")]
            txt = " ".join(f"{v:7.3f}" if v is not None else "    n/a" for v in vals)
            rm = [m.get(k) for k in ("rmse", "rmse_star")]
            txt += " " + " ".join(f"{v:8.3f}" if v is not None else "     n/a" for v in rm)
            lines.append(f"{str(m['metric'])[:32]:32s} {m['n']:4d} {txt}")
        for name, why in s.get("untrained_backbone", {}).items():
            lines.append(f"WARNING: {name}: {why}; not the published metric")
    if s["n_input_problems"]:
        lines.append(f"{s['n_input_problems']} input problem(s) found; see tables/problems.csv")
    return "\n".join(lines)


def write_tables(a: Analysis, out: Path) -> dict[str, Path]:
    """Every table of the report as CSV."""
    t: dict[str, pd.DataFrame] = {}
    t["exclusions"] = pd.DataFrame([x.__dict__ for x in a.exclusions],
                                   columns=["kind", "who", "reason", "rule"])
    t["outliers"] = pd.DataFrame([r.__dict__ for r in a.outliers.removed],
                                 columns=["rater", "method", "statistic", "critical", "value",
                                          "reason"])
    if a.outliers.table is not None:
        t["screening"] = a.outliers.table.reset_index()
    if a.quality is not None:
        t["data_quality"] = a.quality.reset_index()
    if a.reliability is not None:
        rel = a.reliability
        rows = [{"type": k, "icc": v, "ci95_low": rel.icc_ci[k][0],
                 "ci95_high": rel.icc_ci[k][1], "method": rel.method,
                 "n_stimuli": rel.n_stimuli, "n_raters": rel.n_raters}
                for k, v in rel.icc.items()]
        if rel.complete_case:
            cc = rel.complete_case
            rows += [{"type": k, "icc": v, "ci95_low": cc["ci"][k][0],
                      "ci95_high": cc["ci"][k][1],
                      "method": "pingouin, complete-case subset", "n_stimuli": cc["n_stimuli"],
                      "n_raters": rel.n_raters} for k, v in cc["icc"].items()]
        t["icc"] = pd.DataFrame(rows)
        t["inter_rater"] = rel.inter_rater.rename_axis("rater")
        t["intra_rater"] = rel.intra_rater.rename_axis("rater").reset_index()
    sc = a.scores
    if sc.rater_bias is not None:
        t["raters"] = pd.DataFrame({
            "rater": sc.raters, "bias": sc.rater_bias, "bias_ci95_low": sc.rater_bias_ci[:, 0],
            "bias_ci95_high": sc.rater_bias_ci[:, 1], "inconsistency": sc.rater_inconsistency,
            "inconsistency_ci95_low": sc.rater_inconsistency_ci[:, 0],
            "inconsistency_ci95_high": sc.rater_inconsistency_ci[:, 1]})
    if sc.content_ambiguity is not None:
        t["content_ambiguity"] = pd.DataFrame({
            "reference": sc.content, "ambiguity": sc.content_ambiguity,
            "ci95_low": sc.content_ambiguity_ci[:, 0], "ci95_high": sc.content_ambiguity_ci[:, 1]})
    if a.ceiling is not None:
        t["ceiling"] = pd.DataFrame(a.ceiling.summary()).T.rename_axis("statistic")
    if a.ci_curve is not None:
        c = a.ci_curve
        frame = pd.DataFrame({"n_raters": c.n_raters.astype(int),
                              "mean_mos_ci95_width": c.mean_width,
                              "power_law_fit": c.a * c.n_raters ** (-c.b)})
        if c.dmos_width is not None:
            frame["mean_dmos_ci95_width"] = c.dmos_width
            red = c.reduction_per_rater()
            frame["reduction_by_this_rater"] = [red.get(int(n), np.nan) for n in c.n_raters]
        t["ci_vs_raters"] = frame
    if a.metrics is not None:
        t["metrics"] = a.metrics.table
        t["metrics_per_method"] = a.metrics.per_method
        t["significance_p"] = a.metrics.significance.rename_axis("metric")
        t["williams_p"] = a.metrics.williams.rename_axis("metric")
        t["comparisons"] = a.metrics.comparisons
    t["problems"] = pd.DataFrame([p.__dict__ for p in a.problems],
                                 columns=["source", "row", "message"])
    paths = {}
    (out / "tables").mkdir(parents=True, exist_ok=True)
    for name, frame in t.items():
        path = out / "tables" / f"{name}.csv"
        keep_index = name in ("inter_rater", "ceiling", "significance_p", "williams_p")
        frame.to_csv(path, index=keep_index)
        paths[name] = path
    return paths


def _with_ci(frame: pd.DataFrame) -> pd.DataFrame:
    """Display form: ``x``, ``x_ci95_low`` and ``x_ci95_high`` become one ``x [95% CI]``
    column (the CSV tables keep them apart)."""
    out = frame.copy()
    for col in list(frame.columns):
        lo, hi = f"{col}_ci95_low", f"{col}_ci95_high"
        if lo in frame.columns and hi in frame.columns:
            out[col] = [
                "" if not np.isfinite(v) else
                f"{v:.3f}" + ("" if not (np.isfinite(a) and np.isfinite(b))
                              else f" [{a:.3f}, {b:.3f}]")
                for v, a, b in zip(frame[col].astype(float), frame[lo].astype(float),
                                   frame[hi].astype(float), strict=True)]
            out = out.drop(columns=[lo, hi])
    return out


def _fmt(v: Any) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (float, np.floating)):
        return "" if not math.isfinite(float(v)) else f"{float(v):.4g}"
    if v is None or v is pd.NA:
        return ""
    return str(v)


def _table_html(frame: pd.DataFrame, *, index: bool = False, max_rows: int = 200,
                classes: str = "t") -> str:
    if len(frame) > max_rows:
        frame = frame.head(max_rows)
    f = frame.copy()
    for col in f.columns:
        f[col] = [_fmt(v) for v in f[col]]
    if index:
        f.index = [_fmt(v) for v in f.index]
    return ("<div class='scroll'>" + f.to_html(index=index, na_rep="", border=0,
                                               classes=classes, escape=True) + "</div>")


def _quality_display(q: pd.DataFrame) -> pd.DataFrame:
    """The data-quality table in a width a screen can show (the CSV keeps every column)."""

    def num(v: Any) -> float:
        try:
            return float(v)
        except (TypeError, ValueError):
            return float("nan")

    rows = []
    for rater, r in q.iterrows():
        answered = ""
        if np.isfinite(num(r.get("n_ratings"))) and np.isfinite(num(r.get("n_planned"))):
            answered = (f"{int(num(r['n_ratings']))}/{int(num(r['n_planned']))} "
                        f"({num(r.get('completeness')):.0%})")
        timing = ", ".join(x for x in (
            str(r.get("timing_mode") or ""),
            {True: "vsync on", False: "vsync off"}.get(
                None if pd.isna(r.get("vsync")) else bool(r.get("vsync")), "")) if x)
        frames = ""
        if np.isfinite(num(r.get("presentations"))) and \
                np.isfinite(num(r.get("dropped_frames"))):
            frames = (f"{int(num(r.get('dropped_frames')))} dropped in "
                      f"{int(np.nan_to_num(num(r.get('trials_with_drops'))))}/"
                      f"{int(num(r['presentations']))}")
            if num(r.get("requeued")) > 0:
                frames += f"; {int(num(r['requeued']))} re-queued"
        rows.append({
            "rater": rater, "status": r.get("status", ""), "answered": answered,
            "timing": timing,
            "pre-flight": "skipped" if r.get("preflight_skipped") is True
            or str(r.get("preflight_skipped")) == "True" else "",
            "frames": frames,
            "view s": num(r.get("median_viewing_s")), "toggles": num(r.get("median_toggles")),
            "hidden ref": num(r.get("hidden_ref_mean_share")),
            "r others": num(r.get("loo_r")), "repeat r": num(r.get("repeat_r")),
            "flags": r.get("flags", ""),
        })
    out = pd.DataFrame(rows).set_index("rater")
    return out.loc[:, [c for c in out.columns
                       if not (out[c].astype(str).isin(["", "nan"]).all())]]


_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:1.5em auto;padding:0 1em;
color:#222;line-height:1.35}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;
margin-top:1.6em}
table.t{border-collapse:collapse;font-size:.82em;margin:.5em 0}
table.t td,table.t th{border:1px solid #ddd;padding:2px 6px;text-align:right;vertical-align:top}
table.t td{white-space:nowrap}table.t td:last-child{white-space:normal;max-width:38em}
table.t td:last-child{text-align:left}
.warn{background:#fee;border:2px solid #c00;padding:.6em .8em;margin:.6em 0}
.glance{background:#f4f7fb;border:1px solid #9ab;padding:.6em 1em;margin:.8em 0}
.glance h2{margin-top:.2em;border:none;font-size:1.15em}
.glance li{margin:.15em 0}.ok{color:#060}.bad{color:#a00;font-weight:bold}
.notes{background:#f5f5f5;padding:.8em;white-space:pre-wrap}
.scroll{overflow-x:auto;max-width:100%}
.small{font-size:.85em;color:#555}
figure{margin:1em 0}img{max-width:100%}figcaption{font-size:.85em;color:#555}"""


def _glance(a: Analysis, s: dict[str, Any]) -> str:
    """The first screen: what is in the numbers, what is not, and why."""
    esc = html.escape
    items = []
    info = a.ratings.rater_info
    from_sessions = info is not None and "files" in info.columns and info["files"].notna().any()
    items.append(f"<li><b>{s['n_raters_used']}</b> raters used of {s['n_raters_input']} "
                 f"participants with valid ratings; {s['n_stimuli']} stimuli, "
                 f"{s['n_ratings_used']} ratings. Score model: {esc(s['model_name'])}.</li>")
    refused = [x for x in s["exclusions"] if x["kind"] == "refused session"]
    dups = [x for x in s["exclusions"] if x["kind"] == "duplicate session"]
    if refused:
        items.append(f"<li class='bad'>{len(refused)} session file(s) refused:<ul>"
                     + "".join(f"<li>{esc(Path(x['who']).name)}: {esc(x['reason'])}</li>"
                               for x in refused) + "</ul></li>")
    elif from_sessions:
        items.append("<li class='ok'>No session refused (study ids and manifest checksums "
                     "match; none withdrawn).</li>")
    if dups:
        items.append(f"<li>{len(dups)} duplicate session file(s) not used:<ul>"
                     + "".join(f"<li>{esc(Path(x['who']).name)}: {esc(x['reason'])}</li>"
                               for x in dups) + "</ul></li>")
    partial = [x for x in s["exclusions"] if x["kind"] == "partial rater"]
    rule = f"--min-completeness {s['min_completeness']:g}"
    if partial:
        items.append(f"<li class='bad'>{len(partial)} partial session(s) left out ({rule}):"
                     "<ul>" + "".join(f"<li>{esc(x['who'])}: {esc(x['reason'])}</li>"
                                      for x in partial) + "</ul></li>")
    if s["partial_kept"]:
        items.append("<li>Partial session(s) kept (at or above the "
                     f"{s['min_completeness']:.0%} of {esc(rule)}): "
                     + ", ".join(f"{esc(p['rater'])} ({p['completeness']:.0%} of the planned "
                                 "trials)" for p in s["partial_kept"]) + ".</li>")
    if not partial and not s["partial_kept"]:
        items.append(f"<li class='ok'>Every rater completed their session ({esc(rule)}).</li>")
    removed = s["removed_raters"]
    if removed:
        items.append(f"<li class='bad'>{len(removed)} rater(s) removed by the screening "
                     f"({esc(s['outlier_method'])}):<ul>"
                     + "".join(f"<li>{esc(r['rater'])}: {esc(r['reason'])}</li>"
                               for r in removed) + "</ul></li>")
    else:
        items.append(f"<li class='ok'>No rater removed by the screening "
                     f"({esc(s['outlier_method'])}).</li>")
    near = [r for r in s["screening"] if str(r.get("reason") or "").startswith("near-miss")]
    if near:
        items.append(f"<li>{len(near)} near-miss(es) kept: "
                     + ", ".join(esc(str(r["rater"])) for r in near)
                     + " (see <a href='#screening'>Rater screening</a>).</li>")
    flagged = [r for r in s["data_quality"] if r.get("flags") and r.get("status") == "used"]
    if flagged:
        items.append(f"<li>{len(flagged)} rater(s) with data-quality flags: "
                     + ", ".join(esc(str(r["rater"])) for r in flagged)
                     + " (see <a href='#quality'>Data quality</a>).</li>")
    if s["model_fallback"]:
        items.append(f"<li class='bad'>{esc(s['model_fallback'])}</li>")
    for name, why in s.get("untrained_backbone", {}).items():
        items.append(f"<li class='bad'>{esc(name)}: {esc(why)}; its correlations say nothing "
                     "about the published metric.</li>")
    if s["n_input_problems"]:
        items.append(f"<li>{s['n_input_problems']} input problem(s) (rows left out); see "
                     "<a href='#problems'>Input problems</a>.</li>")
    return ("<div class='glance'><h2>At a glance: what went into these numbers</h2><ul>"
            + "".join(items) + "</ul></div>")


def _methods_html(a: Analysis) -> str:
    c = a.config
    t = THRESHOLDS
    rows = [
        ("Score model", f"--model {c.model}", "SUREAL's maximum-likelihood subject model (Li & "
         "Bampis 2020): quality with rater bias and inconsistency and content ambiguity; if "
         "it diverges, its ITU-T P.910 variant (MLE_CO_AP2) is used and this report says so."),
        ("DMOS", "P.910", "DMOS(v) = Q(v) - Q(ref(v)) + top of the scale, Q(ref) from the "
         "hidden reference."),
        ("DMOS 95% CI", f"{c.n_boot} rater resamples", "bootstrap over raters with the model's "
         "rater parameters fixed; keeps the covariance of Q(v) and Q(ref); half-width "
         "t(n_eff-1) sqrt(n/(n-1)) sd. Coverage checked by benchmarks/bench_coverage.py."),
        ("Completeness", f"--min-completeness {c.min_completeness:g}", "raters who answered "
         "less than this share of their planned trials are left out: their bias and "
         "inconsistency would rest on too few ratings, and their ratings cover only part of "
         "the conditions. 0 keeps everyone."),
        ("Screening", f"--outliers {c.outliers}", "p913: removed when r1 < 0.75 and r2 < 0.8 "
         "against the leave-one-out panel (ITU-T P.913), iterated, AND the P.910 MLE "
         "inconsistency is an outlier (robust z > 3.5, Iglewicz-Hoaglin). grubbs: the CGVQM+D "
         "paper's iterative Grubbs test on the mean absolute deviation (mixes bias with "
         "inconsistency; kept to reproduce the paper)."),
        ("Significance level", f"--alpha {c.alpha:g}", "one-tailed tests between metrics; no "
         "correction for multiple comparisons (P.1401 7.6.5 discusses one)."),
        ("Metric intervals", f"{c.n_boot} resamples", "two-way bootstrap (raters and stimuli, "
         "stratified by method), mapping refitted in every resample, basic interval on "
         "Fisher's z (log for rmse) with a small-sample widening of its spread."),
        ("RMSE, RMSE*", "P.1401", "sqrt(sum e^2 / (N - d)), d = parameters of the mapping (5 "
         "logistic, 2 line); RMSE* shrinks each error by the DMOS 95% CI first; outlier ratio: "
         "share of errors beyond the CI."),
        ("Human ceiling", f"{c.n_splits} split-halves", "half of the raters predicting the "
         "other half (plain-mean DMOS), Spearman-Brown corrected PLCC alongside."),
        ("Reliability", "ICC", "pingouin on complete data; REML variance components on all "
         "cells when raters saw different subsets (complete-case values beside)."),
        ("Data-quality flags", "", ", ".join(f"{k} {v:g}" for k, v in t.items())
         + " (flags inform; they do not remove anyone)."),
        ("Seed", f"--seed {c.seed}", "every resample and split is reproducible."),
    ]
    frame = pd.DataFrame(rows, columns=["what", "setting", "meaning"])
    return "<h2>Methods and defaults</h2>" + _table_html(frame)


def write_html(a: Analysis, out: Path, figures: dict[str, tuple[Path, str]],
               notes: str | None = None) -> Path:
    s = summary(a)
    esc = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>Analysis of "
             f"{esc(s['study'])}</title><style>{_CSS}</style></head><body>",
             f"<h1>Analysis of {esc(s['study'])}</h1>",
             f"<p class='small'>Input: {esc(str(s['source']))}. Generated "
             f"{datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')} by cgvq-analyze "
             f"{__version__}; seed {s['seed']}, {s['n_bootstrap']} bootstrap resamples, "
             f"{s['n_splits']} split-halves.</p>",
             _glance(a, s)]
    if notes:
        parts.append(f"<h2>Notes</h2><div class='notes'>{esc(notes)}</div>")

    def fig(name: str) -> None:
        if name in figures:
            path, caption = figures[name]
            parts.append(f"<figure><img src='figures/{esc(path.name)}' alt='{esc(caption)}'>"
                         f"<figcaption>{esc(caption)}</figcaption></figure>")

    if a.metrics is not None:
        m = a.metrics
        parts.append("<h2 id='metrics'>Metrics versus humans</h2><p>PLCC and rmse after the "
                     "5-parameter logistic mapping, SRCC and KRCC on the scores oriented by "
                     "their direction (higher = better quality); rmse and rmse* per ITU-T "
                     "P.1401 (N - d); outlier ratio: share of stimuli whose error exceeds "
                     "their DMOS 95% CI. 95% CIs from a two-way bootstrap (raters and "
                     "stimuli, mapping refitted each time). Hidden references excluded. The "
                     "last row is the human ceiling (half of the raters predicting the other "
                     "half).</p>")
        if m.untrained:
            parts.append("<div class='warn'>Flagged metrics (not the published metric): "
                         + "; ".join(f"{esc(k)}: {esc(v)}" for k, v in m.untrained.items())
                         + "</div>")
        if m.not_applicable:
            parts.append("<p>Not applicable to these stimuli (no score, so not in the table "
                         "where no stimulus was scored): "
                         + "; ".join(f"{esc(k)}: {esc(v)}" for k, v in m.not_applicable.items())
                         + "</p>")
        shown = _with_ci(m.table)
        shown["flag"] = ["FLAGGED (see above)" if f else "" for f in shown["flag"].fillna("")]
        parts.append(_table_html(shown))
        fig("metric_benchmark")
        if len(m.significance):
            parts.append(f"<p>One-tailed paired bootstrap test (the paper's table): p-value "
                         f"that the row metric's PLCC exceeds the column metric's; significant "
                         f"below {m.alpha}.</p>" + _table_html(m.significance, index=True))
            parts.append("<p>Williams' t (dependent correlations sharing the DMOS), one-tailed "
                         "p-value that the row metric's PLCC exceeds the column's:</p>"
                         + _table_html(m.williams, index=True))
            parts.append("<details><summary>All comparisons, overall and per distortion "
                         "method (bootstrap, Williams, Steiger, P.1401 F-tests on rmse and "
                         "rmse*)</summary>" + _table_html(m.comparisons, max_rows=5000)
                         + "</details>")
        if len(m.per_method):
            parts.append("<p>Per distortion method (mapping fitted on all stimuli; rmse "
                         "without the N - d correction):</p>"
                         + _table_html(_with_ci(m.per_method), max_rows=2000))
        fig("metric_per_method")
        fig("metric_comparison")
        fig("metric_scatter")
    parts.append("<h2 id='dmos'>DMOS</h2><p>DMOS = Q(v) - Q(ref) + "
                 f"{a.screened.ref_score:g} (ITU-T P.910, hidden reference), Q from "
                 f"{esc(s['model_name'])}; 95% CIs from {a.config.n_boot} resamples of the "
                 "raters; full table in dmos.csv.</p>")
    fig("dmos_per_scene")
    cols = ["stimulus", "reference", "method", "level", "dmos", "ci95_low", "ci95_high", "mos",
            "n_ratings"]
    parts.append("<details><summary>DMOS table</summary>"
                 + _table_html(a.dmos()[cols], max_rows=5000) + "</details>")
    parts.append("<h2 id='quality'>Data quality</h2><p>One row per participant with valid "
                 "ratings, also those left out. timing = the session's timing mode (vsync; "
                 "paced-pilot when the experimenter allowed no vsync; simulated for "
                 "simulated raters, who have no pre-flight) and whether vsync was "
                 "on; r others = Pearson r with the mean of all other raters; repeat r = "
                 "mean r between the rater's repetitions. Flag thresholds: "
                 + esc(", ".join(f"{k} {v:g}" for k, v in THRESHOLDS.items()))
                 + "; flags inform, they do not remove anyone.</p>")
    if a.quality is not None:
        parts.append(_table_html(_quality_display(a.quality), index=True, max_rows=2000))
        parts.append("<p class='small'>answered = rated / planned trials (completeness); "
                     "frames = dropped frames in presentations with drops / all "
                     "presentations; view s = median viewing time; hidden ref = mean "
                     "hidden-reference rating as a share of the scale. Every column is in "
                     "tables/data_quality.csv.</p>")
    fig("rater_agreement")
    parts.append(f"<h2 id='screening'>Rater screening ({esc(a.outliers.method)})</h2>")
    if a.outliers.removed:
        parts.append(_table_html(pd.DataFrame([r.__dict__ for r in a.outliers.removed])))
    else:
        parts.append(f"<p>No rater removed ({esc(a.outliers.method)}).</p>")
    if a.outliers.table is not None:
        parts.append("<p>Statistics of every rater (r1: with the leave-one-out panel mean; r2: "
                     "per-HRC means; inconsistency: MLE noise s.d. and its robust z; n_raters: "
                     "panel size when last tested). Removals and near-misses are explained."
                     "</p>" + _table_html(a.outliers.table, index=True, max_rows=2000))
    for note in a.outliers.notes:
        if note:
            parts.append(f"<p class='small'>{esc(note)}</p>")
    if a.scores.rejected:
        parts.append("<p>Rejected inside the BT.500 score model: "
                     f"{esc(', '.join(a.scores.rejected))}.</p>")
    parts.append("<h2>Reliability</h2>")
    if a.reliability is not None:
        rel = a.reliability
        parts.append(_table_html(pd.DataFrame(
            [{"ICC": k, "value": v, "95% CI": f"[{rel.icc_ci[k][0]:.3f}, {rel.icc_ci[k][1]:.3f}]"}
             for k, v in rel.icc.items()])))
        parts.append(f"<p>{esc(rel.method)}; ratings averaged over repetitions; "
                     f"{rel.n_stimuli} stimuli, {rel.n_raters} raters, {rel.n_targets} "
                     "stimuli rated by every rater.</p>")
        if rel.complete_case:
            cc = rel.complete_case
            parts.append(f"<p>Complete-case subset (pingouin, only the {cc['n_stimuli']} "
                         f"stimuli every rater rated): "
                         + esc(", ".join(f"{k} {v:.3f}" for k, v in cc["icc"].items()))
                         + ".</p>")
    fig("inter_rater")
    fig("intra_rater")
    parts.append("<h2>Raters and contents</h2>")
    fig("rater_bias")
    fig("content_ambiguity")
    parts.append("<h2>Human ceiling and panel size</h2>")
    if "ceiling" in s:
        parts.append(_table_html(pd.DataFrame(a.ceiling.summary()).T.rename_axis("statistic"),
                                 index=True))
        parts.append(f"<p class='small'>{a.ceiling.n_stimuli} distorted stimuli; a split uses "
                     f"those both halves rated (median {a.ceiling.median_used:g}).</p>")
    if a.ci_curve is not None:
        parts.append(f"<p>{esc(_curve_text(a))}</p>")
    fig("split_half")
    fig("ci_vs_raters")
    parts.append(f"<h2 id='problems'>Input problems ({len(a.problems)})</h2>")
    if a.problems:
        parts.append(_table_html(pd.DataFrame([p.__dict__ for p in a.problems]),
                                 max_rows=2000))
    parts.append(_methods_html(a))
    parts.append("<h2>Files</h2><ul><li>dmos.csv (cgvq-dmos/1)</li><li>sureal_dataset.json"
                 "</li><li>rating_matrix_p910.csv</li><li>summary.json</li>"
                 "<li>tables/*.csv</li><li>figures/*.png</li></ul></body></html>")
    path = out / "report.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


def _curve_text(a: Analysis) -> str:
    c = a.ci_curve
    txt = (f"Mean MOS 95% CI width follows {c.a:.3g} n^-{c.b:.3f} (b measures how the width "
           "itself shrinks; 0.5 for independent raters, larger at small n).")
    red = c.reduction_per_rater()
    if c.dmos_width is not None and red:
        first = min(red, key=lambda n: abs(n - 5))
        last = max(red)
        txt += (f" The paper's reading: the average DMOS 95% CI width shrinks by "
                f"{red[first]:.3g} when the {first}th participant is added and by "
                f"{red[last]:.3g} for the {last}th; fitted from the 5th on, this reduction "
                f"decays as exp(-{c.decay_rate:.3f} n) (power law: n^-{c.reduction_power:.2f})."
                " The CGVQM+D paper reports 1.83 at the 5th and 0.12 at the 20th participant "
                "and a decay rate of 0.19 for this reduction; it is not comparable with b.")
    return txt


def write_report(a: Analysis, out: str | Path, *, notes: str | None = None) -> Path:
    """Write the full report folder and return the path of report.html."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_dmos_csv(a.screened, a.scores, out / "dmos.csv")
    write_sureal_json(a.ratings, out / "sureal_dataset.json")
    write_rating_matrix(a.ratings, out / "rating_matrix_p910.csv")
    write_tables(a, out)
    figures = draw_all(a, out / "figures")
    (out / "summary.json").write_text(json.dumps(summary(a), indent=1, default=_num),
                                      encoding="utf-8")
    return write_html(a, out, figures, notes)
