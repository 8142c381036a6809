"""The report folder: report.html, figures/*.png, dmos.csv, tables as CSV, summary.json."""

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
from .sureal_io import write_sureal_json

log = logging.getLogger(__name__)

SUMMARY_FORMAT = "cgvq-analysis-summary/1"


def _num(x: Any) -> Any:
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x


def summary(a: Analysis) -> dict[str, Any]:
    """Machine-readable results (the demo and scripts read ``summary.json``)."""
    rs, sc = a.screened, a.scores
    out: dict[str, Any] = {
        "format": SUMMARY_FORMAT,
        "study": rs.study,
        "source": a.ratings.source,
        "model": sc.model,
        "model_name": sc.model_name,
        "outlier_method": a.outliers.method,
        "seed": a.config.seed,
        "n_bootstrap": a.config.n_boot,
        "n_splits": a.config.n_splits,
        "n_raters_input": a.ratings.n_raters,
        "n_raters_used": rs.n_raters,
        "n_stimuli": rs.n_stimuli,
        "n_ratings_used": rs.n_ratings,
        "removed_raters": [
            {"rater": r.rater, "method": r.method, "statistic": _num(r.statistic),
             "critical": _num(r.critical), "value": _num(r.value), "reason": r.reason}
            for r in a.outliers.removed
        ],
        "model_rejected_raters": list(sc.rejected),
        "n_input_problems": len(a.problems),
        "timings_s": {k: round(v, 3) for k, v in a.timings.items()},
    }
    if a.reliability is not None:
        out["icc"] = {k: _num(v) for k, v in a.reliability.icc.items()}
        out["icc_ci95"] = {k: [_num(v[0]), _num(v[1])] for k, v in a.reliability.icc_ci.items()}
        out["intra_rater_mean_r"] = _num(a.reliability.intra_rater.mean())
    if a.ceiling is not None:
        out["ceiling"] = {k: {kk: _num(vv) for kk, vv in v.items()}
                          for k, v in a.ceiling.summary().items()}
    if a.ci_curve is not None:
        red = a.ci_curve.reduction_per_rater()
        out["ci_curve"] = {"power_law_a": _num(a.ci_curve.a), "power_law_b": _num(a.ci_curve.b),
                           "reduction_per_added_rater": {str(k): _num(v) for k, v in red.items()}}
    if a.metrics is not None:
        out["metrics"] = [{k: _num(v) for k, v in row.items()}
                          for row in a.metrics.table.to_dict("records")]
        out["untrained_backbone"] = dict(a.metrics.untrained)
        out["significance_p"] = {
            r: {c: _num(a.metrics.significance.loc[r, c]) for c in a.metrics.significance.columns}
            for r in a.metrics.significance.index}
    return out


def summary_text(a: Analysis) -> str:
    """A short terminal summary."""
    s = summary(a)
    lines = [f"study {s['study']}: {s['n_stimuli']} stimuli, {s['n_raters_used']} of "
             f"{s['n_raters_input']} raters, {s['n_ratings_used']} ratings; model "
             f"{s['model_name']}"]
    if s["removed_raters"]:
        lines.append("removed raters (" + s["outlier_method"] + "): "
                     + ", ".join(r["rater"] for r in s["removed_raters"]))
    else:
        lines.append(f"removed raters ({s['outlier_method']}): none")
    if "icc" in s:
        lines.append(f"ICC(2,k) {s['icc']['ICC(2,k)']:.3f}   ICC(3,k) {s['icc']['ICC(3,k)']:.3f}")
    if "ceiling" in s:
        c = s["ceiling"]["plcc"]
        lines.append(f"human ceiling (split-half PLCC) {c['median']:.3f} "
                     f"[{c['ci95_low']:.3f}, {c['ci95_high']:.3f}]")
    if "metrics" in s:
        lines.append(f"{'metric':32s} {'n':>4s} {'PLCC':>7s} {'SRCC':>7s} {'KRCC':>7s} "
                     f"{'RMSE':>8s}")
        for m in s["metrics"]:
            vals = [m.get(k) for k in ("plcc", "srcc", "krcc", "rmse")]
            txt = " ".join(f"{v:7.3f}" if v is not None else "    n/a" for v in vals)
            lines.append(f"{str(m['metric'])[:32]:32s} {m['n']:4d} {txt}")
        for name, backbone in s.get("untrained_backbone", {}).items():
            lines.append(f"WARNING: {name} ran on an untrained backbone ({backbone})")
    if s["n_input_problems"]:
        lines.append(f"{s['n_input_problems']} input problem(s) found; see problems.csv")
    return "\n".join(lines)


def write_tables(a: Analysis, out: Path) -> dict[str, Path]:
    """Every table of the report as CSV."""
    t: dict[str, pd.DataFrame] = {}
    t["outliers"] = pd.DataFrame([r.__dict__ for r in a.outliers.removed],
                                 columns=["rater", "method", "statistic", "critical", "value",
                                          "reason"])
    if a.outliers.deviation:
        t["rater_screening"] = pd.Series(a.outliers.deviation, name="screening_value") \
            .rename_axis("rater").reset_index()
    if a.reliability is not None:
        rel = a.reliability
        t["icc"] = pd.DataFrame([{"type": k, "icc": v, "ci95_low": rel.icc_ci[k][0],
                                  "ci95_high": rel.icc_ci[k][1], "n_stimuli": rel.n_targets}
                                 for k, v in rel.icc.items()])
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
        t["ci_vs_raters"] = pd.DataFrame({"n_raters": c.n_raters.astype(int),
                                          "mean_ci95_width": c.mean_width,
                                          "power_law_fit": c.a * c.n_raters ** (-c.b)})
    if a.metrics is not None:
        t["metrics"] = a.metrics.table
        t["metrics_per_method"] = a.metrics.per_method
        t["significance_p"] = a.metrics.significance.rename_axis("metric")
    t["problems"] = pd.DataFrame([p.__dict__ for p in a.problems],
                                 columns=["source", "row", "message"])
    paths = {}
    (out / "tables").mkdir(parents=True, exist_ok=True)
    for name, frame in t.items():
        path = out / "tables" / f"{name}.csv"
        keep_index = name in ("inter_rater", "ceiling", "significance_p")
        frame.to_csv(path, index=keep_index)
        paths[name] = path
    return paths


def _table_html(frame: pd.DataFrame, *, index: bool = False, max_rows: int = 200) -> str:
    if len(frame) > max_rows:
        frame = frame.head(max_rows)
    return frame.to_html(index=index, float_format=lambda v: f"{v:.4g}", na_rep="",
                         border=0, classes="t", escape=True)


_CSS = """body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table.t{border-collapse:collapse;font-size:.85em;margin:.5em 0}
table.t td,table.t th{border:1px solid #ddd;padding:2px 6px;text-align:right}
.warn{background:#fee;border:2px solid #c00;padding:.8em;font-weight:bold}
.notes{background:#f5f5f5;padding:.8em;white-space:pre-wrap}
figure{margin:1em 0}img{max-width:100%}figcaption{font-size:.85em;color:#555}"""


def write_html(a: Analysis, out: Path, figures: dict[str, tuple[Path, str]],
               notes: str | None = None) -> Path:
    s = summary(a)
    esc = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>Analysis of "
             f"{esc(s['study'])}</title><style>{_CSS}</style></head><body>",
             f"<h1>Analysis of {esc(s['study'])}</h1>"]
    if a.metrics is not None and a.metrics.untrained:
        items = "".join(f"<li>{esc(k)}: backbone {esc(v)}</li>"
                        for k, v in a.metrics.untrained.items())
        parts.append("<div class='warn'>Warning: these metric scores come from an UNTRAINED "
                     f"(random) backbone, so their correlations say nothing about the published "
                     f"metric:<ul>{items}</ul></div>")
    if notes:
        parts.append(f"<h2>Notes</h2><div class='notes'>{esc(notes)}</div>")
    parts.append(
        f"<p>{s['n_stimuli']} stimuli, {s['n_raters_used']} of {s['n_raters_input']} raters, "
        f"{s['n_ratings_used']} ratings. Score model: {esc(s['model_name'])}. Outlier "
        f"screening: {esc(s['outlier_method'])}. Seed {s['seed']}, {s['n_bootstrap']} "
        f"bootstrap resamples, {s['n_splits']} split-halves. Input: {esc(str(s['source']))}. "
        f"Generated {datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')} by cgvq-analyze "
        f"{__version__}.</p>")

    def fig(name: str) -> None:
        if name in figures:
            path, caption = figures[name]
            parts.append(f"<figure><img src='figures/{esc(path.name)}' alt='{esc(caption)}'>"
                         f"<figcaption>{esc(caption)}</figcaption></figure>")

    if a.metrics is not None:
        parts.append("<h2>Metrics versus humans</h2><p>PLCC and RMSE after the 5-parameter "
                     "logistic mapping, SRCC and KRCC on raw scores (sign as is); 95% "
                     "bootstrap CIs over stimuli; hidden references excluded. The last row is "
                     "the human ceiling (half of the raters predicting the other half).</p>")
        parts.append(_table_html(a.metrics.table))
        if len(a.metrics.significance):
            parts.append(f"<p>One-tailed paired bootstrap p-value that the row metric's PLCC "
                         f"exceeds the column metric's (significant below {a.metrics.alpha}):"
                         "</p>" + _table_html(a.metrics.significance, index=True))
        if len(a.metrics.per_method):
            parts.append("<p>Per distortion method:</p>" + _table_html(a.metrics.per_method))
        fig("metric_comparison")
        fig("metric_scatter")
    parts.append("<h2>DMOS</h2><p>DMOS = Q(v) - Q(ref) + "
                 f"{a.screened.ref_score:g} (ITU-T P.910, hidden reference), Q from "
                 f"{esc(s['model_name'])}; full table in dmos.csv.</p>")
    fig("dmos_per_scene")
    cols = ["stimulus", "reference", "method", "level", "dmos", "ci95_low", "ci95_high", "mos",
            "n_ratings"]
    parts.append("<details><summary>DMOS table</summary>"
                 + _table_html(a.dmos()[cols], max_rows=2000) + "</details>")
    parts.append("<h2>Outlier raters</h2>")
    if a.outliers.removed:
        parts.append(_table_html(pd.DataFrame([r.__dict__ for r in a.outliers.removed])))
    else:
        parts.append(f"<p>No rater removed ({esc(a.outliers.method)}).</p>")
    if a.scores.rejected:
        parts.append("<p>Rejected inside the BT.500 score model: "
                     f"{esc(', '.join(a.scores.rejected))}.</p>")
    parts.append("<h2>Reliability</h2>")
    if a.reliability is not None:
        rel = a.reliability
        parts.append(_table_html(pd.DataFrame(
            [{"ICC": k, "value": v, "95% CI": f"[{rel.icc_ci[k][0]:.3f}, {rel.icc_ci[k][1]:.3f}]"}
             for k, v in rel.icc.items()])))
        parts.append(f"<p>On ratings averaged over repetitions, {rel.n_targets} stimuli rated "
                     "by every rater (pingouin).</p>")
    fig("inter_rater")
    fig("intra_rater")
    parts.append("<h2>Raters and contents</h2>")
    fig("rater_bias")
    fig("content_ambiguity")
    parts.append("<h2>Human ceiling and panel size</h2>")
    if "ceiling" in s:
        parts.append(_table_html(pd.DataFrame(a.ceiling.summary()).T.rename_axis("statistic"),
                                 index=True))
    if "ci_curve" in s:
        c = a.ci_curve
        red = c.reduction_per_rater()
        first = min(red, key=lambda n: abs(n - 5)) if red else None
        last = max(red) if red else None
        txt = (f"Power law: width = {c.a:.3g} n^-{c.b:.3f}.")
        if first is not None:
            txt += (f" Mean CI reduction from adding rater {first}: {red[first]:.3g}; "
                    f"rater {last}: {red[last]:.3g}.")
        parts.append(f"<p>{esc(txt)}</p>")
    fig("split_half")
    fig("ci_vs_raters")
    parts.append(f"<h2>Input problems ({len(a.problems)})</h2>")
    if a.problems:
        parts.append(_table_html(pd.DataFrame([p.__dict__ for p in a.problems])))
    parts.append("<h2>Files</h2><ul><li>dmos.csv</li><li>sureal_dataset.json</li>"
                 "<li>rating_matrix_p910.csv</li><li>summary.json</li><li>tables/*.csv</li>"
                 "</ul></body></html>")
    path = out / "report.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


def write_report(a: Analysis, out: str | Path, *, notes: str | None = None) -> Path:
    """Write the full report folder and return the path of report.html."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_dmos_csv(a.screened, a.scores, out / "dmos.csv")
    write_sureal_json(a.ratings, out / "sureal_dataset.json")
    write_rating_matrix(a.ratings, out / "rating_matrix_p910.csv")
    write_tables(a, out)
    figures = draw_all(a, out / "figures")
    (out / "summary.json").write_text(json.dumps(summary(a), indent=1), encoding="utf-8")
    return write_html(a, out, figures, notes)
