"""report.html: the analysis rendered through the Jinja2 template ``templates/report.html``.

The template holds the page and its prose; this module gives it the numbers (the summary of
:mod:`analysis.report`), tables already formatted (pandas escapes every cell) and figure
captions. Everything else is escaped by Jinja2's autoescape.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from jinja2 import Environment, FileSystemLoader, select_autoescape
from markupsafe import Markup

from .methods_text import fixed, methods_paragraphs, percent
from .panel import answer_counts_rows
from .pipeline import Analysis
from .presentation_text import metric_viewing_text
from .quality import THRESHOLDS
from .version import __version__

TEMPLATES = Path(__file__).parent / "templates"
DMOS_COLUMNS = ["stimulus", "reference", "method", "level", "dmos", "ci95_low", "ci95_high",
                "mos", "n_ratings"]


def format_value(v: Any) -> str:
    """A cell as the report shows it (yes/no, 4 significant digits, blank for missing)."""
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (float, np.floating)):
        return "" if not math.isfinite(float(v)) else f"{float(v):.4g}"
    if v is None or v is pd.NA:
        return ""
    return str(v)


def format_column(values: pd.Series) -> list[str]:
    """A column as the report shows it. Numbers get one number of decimals per column, so
    that they line up and read alike (4 significant digits for the largest; whole numbers
    none); other columns go cell by cell through :func:`format_value`."""
    if not pd.api.types.is_float_dtype(values):
        return [format_value(v) for v in values]
    x = values.to_numpy(float)
    finite = np.abs(x[np.isfinite(x)])
    if finite.size == 0:
        return ["" for _ in x]
    if np.all(finite == np.round(finite)):
        decimals = 0
    else:
        top = float(finite.max())
        decimals = int(np.clip(3 - math.floor(math.log10(top)) if top > 0 else 3, 0, 4))
    return [f"{v:.{decimals}f}" if math.isfinite(v) else "" for v in x]


def table_html(frame: pd.DataFrame, *, index: bool = False, max_rows: int = 200,
                classes: str = "t") -> Markup:
    """A table as HTML (values formatted and escaped by pandas), at most ``max_rows`` rows."""
    if len(frame) > max_rows:
        frame = frame.head(max_rows)
    f = frame.copy()
    for col in f.columns:
        f[col] = format_column(frame[col])
    if index:
        f.index = [format_value(v) for v in f.index]
    return Markup("<div class='scroll'>" + f.to_html(index=index, na_rep="", border=0,
                                                     classes=classes, escape=True) + "</div>")


def with_ci(frame: pd.DataFrame) -> pd.DataFrame:
    """Display form: ``x``, ``x_ci95_low`` and ``x_ci95_high`` become one ``x [95% CI]``
    column (the CSV tables keep them apart)."""
    out = frame.copy()
    for col in list(frame.columns):
        lo, hi = f"{col}_ci95_low", f"{col}_ci95_high"
        if lo in frame.columns and hi in frame.columns:
            out[col] = [
                "" if not np.isfinite(v) else
                fixed(v) + ("" if not (np.isfinite(a) and np.isfinite(b))
                            else f" [{fixed(a)},\u00a0{fixed(b)}]")  # wraps before '[' only
                for v, a, b in zip(frame[col].astype(float), frame[lo].astype(float),
                                   frame[hi].astype(float), strict=True)]
            out = out.drop(columns=[lo, hi])
    return out


def quality_display(q: pd.DataFrame) -> pd.DataFrame:
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
        mode = r.get("timing_mode")
        mode = "" if mode is None or pd.isna(mode) else str(mode)
        on = {True: "vsync on", False: "vsync off"}.get(
            None if pd.isna(r.get("vsync")) else bool(r.get("vsync")), "")
        timing = mode if (mode, on) == ("vsync", "vsync on") else \
            ", ".join(x for x in (mode, on) if x)  # "vsync, vsync on" says it twice
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
            "minutes": num(r.get("minutes")),
            "view s": num(r.get("median_viewing_s")), "toggles": num(r.get("median_toggles")),
            "hidden ref": num(r.get("hidden_ref_mean_share")),
            "r others": num(r.get("loo_r")), "repeat r": num(r.get("repeat_r")),
            # each check's outcome is in the vision screening table above, and a failed or
            # inconclusive one is a flag here: the row stays narrow enough to show the flags
            "flags": r.get("flags", ""),
        })
    out = pd.DataFrame(rows).set_index("rater")
    # a column nobody has a value in (no session files: no timing, viewing or frames) is
    # left out, and so is its line in the legend (QUALITY_COLUMNS)
    return out.loc[:, [c for c in out.columns if not out[c].replace("", np.nan).isna().all()]]


QUALITY_COLUMNS = {
    "answered": "answered = rated / planned trials (completeness)",
    "timing": "timing = the session's timing mode (vsync; paced-pilot when the experimenter "
              "allowed no vsync; simulated for simulated raters, who have no pre-flight) and "
              "whether vsync was on",
    "frames": "frames = dropped frames in presentations with drops / all presentations",
    "minutes": "minutes = in the study: from each start (or return) to the last thing "
           "recorded before the next, summed (pauses count; the time away between sittings "
           "does not)",
    "view s": "view s = median viewing time per trial",
    "toggles": "toggles = median switches between test and reference per trial",
    "hidden ref": "hidden ref = mean hidden-reference rating as a share of the scale",
    "r others": "r others = Pearson r with the mean of all other raters read, those the "
                "screening removed included (the screening's r1 uses only the raters it "
                "kept, so the two can differ)",
    "repeat r": "repeat r = mean r between the rater's repetitions",
}
"""The legend of each column of the data-quality table, said only for the columns shown."""


def quality_legend(table: pd.DataFrame | None) -> str:
    if table is None:
        return ""
    return "; ".join(text for col, text in QUALITY_COLUMNS.items() if col in table.columns)


#: What each score model is, in the words of a methods section.
_MODEL_TEXT = {
    "mle": "SUREAL's maximum-likelihood subject model (Li et al. 2020): quality with rater "
           "bias and inconsistency and content ambiguity; if it diverges, its ITU-T P.910 "
           "variant (MLE_CO_AP2) is used and this report says so.",
    "p910": "SUREAL's MLE_CO_AP2, the ITU-T P.910 subject model: quality with rater bias and "
            "inconsistency.",
    "mos": "plain mean opinion scores: each stimulus's mean over every rating.",
    "bt500": "ITU-R BT.500 rater rejection (SUREAL's SR_MOS), then plain means over the raters "
             "kept.",
}
#: The estimator each bootstrap resample recomputes (analysis.intervals).
_CI_ESTIMATOR = {
    "mle": "the model's rater parameters fixed (bias-corrected, inconsistency-weighted means)",
    "p910": "the model's rater parameters fixed (bias-corrected, inconsistency-weighted means)",
    "mos": "plain means",
    "bt500": "plain means over the raters kept",
}
#: What each rater screening does.
_SCREENING_TEXT = {
    "p913": "removed when r1 < 0.75 and r2 < 0.8 against the leave-one-out panel (ITU-T "
            "P.913), iterated, AND the P.910 MLE inconsistency is an outlier (robust z > 3.5, "
            "Iglewicz-Hoaglin).",
    "grubbs": "the CGVQM+D paper's iterative Grubbs test on each rater's mean absolute "
              "deviation from the panel (mixes bias with inconsistency; kept to reproduce the "
              "paper).",
    "bt500": "ITU-R BT.500's kurtosis-based rater screening (SUREAL's).",
    "none": "no rater is screened out.",
}
#: The columns of each screening's per-rater table, for the sentence above it.
SCREENING_COLUMNS_TEXT = {
    "p913": "r1: with the leave-one-out panel mean; r2: per-HRC means; inconsistency: MLE "
            "noise s.d. and its robust z; n_raters: panel size when last tested",
    "grubbs": "deviation: mean absolute deviation from the panel mean, before any removal",
    "bt500": "outside_share: share of the rater's votes outside the panel's BT.500 bounds; "
             "one_sidedness: |P-Q|/(P+Q) of those votes",
}


def _screening_text(a: Analysis) -> str:
    """The screening rule as applied: P.913's r2 needs 4 HRCs, and without it r1 decides."""
    text = _SCREENING_TEXT.get(a.config.outliers, a.config.outliers)
    table = a.outliers.table
    if a.config.outliers == "p913" and table is not None and "r2" in table.columns and \
            not table["r2"].notna().any():
        text = text.replace("r1 < 0.75 and r2 < 0.8", "r1 < 0.75 (r2, on per-HRC means, "
                            "needs 4 HRCs and was not computed)")
    return text


def methods_table(a: Analysis) -> pd.DataFrame:
    """The "Methods and defaults" table: every choice of the run and what it means."""
    c = a.config
    t = THRESHOLDS
    rows = [
        ("Score model", f"--model {c.model}", _MODEL_TEXT.get(c.model, c.model)),
        ("DMOS", "P.910", "DMOS(v) = Q(v) - Q(ref(v)) + top of the scale, Q(ref) from the "
         "hidden reference." if (a.screened.reference_index() >= 0).any() else
         "not formed: no hidden reference was rated, so the dmos column holds the quality "
         "scores Q(v)."),
        ("DMOS 95% CI", f"{c.n_boot} rater resamples", "bootstrap over raters with "
         + _CI_ESTIMATOR.get(c.model, "the model's estimator") + "; keeps the covariance of "
         "Q(v) and Q(ref); half-width t(n_eff-1) sqrt(n/(n-1)) sd. Coverage checked by "
         "benchmarks/bench_coverage.py."),
        ("Completeness", f"--min-completeness {c.min_completeness:g}", "raters who answered "
         "less than this share of their planned trials are left out: their bias and "
         "inconsistency would rest on too few ratings, and their ratings cover only part of "
         "the conditions. 0 keeps everyone."),
        ("Screening", f"--outliers {c.outliers}", _screening_text(a)),
        ("Significance level", f"--alpha {c.alpha:g}", "one-tailed tests between metrics; no "
         "correction for multiple comparisons (P.1401 7.6.5 discusses one)."),
        ("Metric intervals", f"{c.n_boot} resamples", "two-way bootstrap (raters and stimuli, "
         "stratified by method), mapping refitted in every resample, bias-corrected "
         "percentile interval on Fisher's z (log for rmse) with a small-sample widening of "
         "its spread."),
        ("RMSE, RMSE*", "P.1401", "sqrt(sum e^2 / (N - d)), d = parameters of the mapping (5 "
         "logistic, 2 line); RMSE* shrinks each error by the DMOS 95% CI first; outlier ratio: "
         "share of errors beyond the CI."),
        ("Human ceiling", f"{c.n_splits} split-halves", "half of the raters predicting the "
         "other half (plain-mean DMOS), Spearman-Brown corrected PLCC alongside."),
        ("Allocation", f"protocol.allocation {a.screened.allocation}", "full: every rater "
         "rates every stimulus equally often. adaptive (or unbalanced counts): the score model "
         "uses every rating; ICC, inter-rater r and the screening use the first rating of each "
         "stimulus per rater (block 1, a complete matrix)."),
        ("Reliability", "ICC", "pingouin on complete data; REML variance components on all "
         "cells when raters saw different subsets (complete-case values beside)."),
        ("Data-quality flags", "", ", ".join(f"{k} {v:g}" for k, v in t.items())
         + " (flags inform; they do not remove anyone)."),
        ("Seed", f"--seed {c.seed}", "every resample and split is reproducible."),
    ]
    return pd.DataFrame(rows, columns=["what", "setting", "meaning"])


def curve_text(a: Analysis) -> str:
    """How the CI width shrinks with the panel size, in words (and against the paper)."""
    c = a.ci_curve
    txt = (f"Mean MOS 95% CI width follows {c.a:.3g} n^-{c.b:.3f} (b measures how the width "
           "itself shrinks; 0.5 for independent raters, larger at small n).")
    red = c.reduction_per_rater()
    if c.dmos_width is not None and red:
        first = min(red, key=lambda n: abs(n - 5))
        last = max(red)
        txt += (f" The CGVQM+D paper's reading: the average DMOS 95% CI width shrinks by "
                f"{red[first]:.3g} when the {ordinal(first)} participant is added")
        txt += (f" and by {red[last]:.3g} for the {ordinal(last)}" if last != first else "")
        if np.isfinite(c.decay_rate):
            txt += (f"; fitted from the {ordinal(c.decay_from)} on, this reduction decays as "
                    f"exp(-{c.decay_rate:.3f} n) (power law: n^-{c.reduction_power:.2f})")
        else:
            txt += "; too few participants to fit how this reduction decays"
        txt += (". The CGVQM+D paper reports 1.83 at the 5th and 0.12 at the 20th participant "
                "and a decay rate of 0.19 for this reduction; it is not comparable with b.")
        span = a.ratings.scale_max - a.ratings.scale_min
        if span != 100:
            txt += (f" The paper's widths are on its 0..100 scale, these on a "
                    f"{a.ratings.scale_min:g}..{a.ratings.scale_max:g} scale: compare them as "
                    f"shares of the range (here {red[first] / span:.2%} and "
                    f"{red[last] / span:.2%}; the paper's 1.83% and 0.12%).")
    return txt


def ordinal(n: int) -> str:
    """1st, 2nd, 3rd, 4th, ..., 11th, 12th, 13th, 21st."""
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def _environment() -> Environment:
    env = Environment(loader=FileSystemLoader(TEMPLATES), autoescape=select_autoescape(["html"]),
                      trim_blocks=True, lstrip_blocks=True)
    env.filters["table"] = table_html
    env.filters["with_ci"] = with_ci
    env.filters["filename"] = lambda p: Path(str(p)).name
    env.filters["percent"] = percent
    return env


def _metric_table(a: Analysis) -> pd.DataFrame | None:
    if a.metrics is None:
        return None
    shown = with_ci(a.metrics.table)
    shown["flag"] = ["FLAGGED (see above)" if f else "" for f in shown["flag"].fillna("")]
    titles = [a.metrics.title(m) for m in shown["metric"]]
    if titles != list(shown["metric"]):  # the name the text and figures print, beside the id
        shown.insert(1, "title", titles)
    return shown


def write_html(a: Analysis, out: Path, figures: dict[str, tuple[Path, str]],
               summary: dict[str, Any], notes: str | None = None) -> Path:
    """Render report.html into ``out`` (``figures``: name -> (png path, caption))."""
    info = a.ratings.rater_info
    context = {
        "a": a, "s": summary, "notes": notes, "version": __version__,
        "methods_text": methods_paragraphs(a, summary),
        "generated": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "css": Markup((TEMPLATES / "report.css").read_text(encoding="utf-8")),
        "figures": figures,
        "from_sessions": bool(info is not None and "files" in info.columns
                              and info["files"].notna().any()),
        "seated": bool((a.ratings.presentation or {}).get("viewing_distance_cm")),
        "metric_viewing": metric_viewing_text(summary.get("viewing"),
                                              summary.get("metric_titles")),
        "near": [r for r in summary["screening"]
                 if str(r.get("reason") or "").startswith("near-miss")],
        "flagged": [r for r in summary["data_quality"]
                    if r.get("flags") and r.get("status") == "used"],
        "thresholds": ", ".join(f"{k} {v:g}" for k, v in THRESHOLDS.items()),
        "metric_table": _metric_table(a),
        "dmos_table": a.dmos()[DMOS_COLUMNS],
        "quality_table": (quality := quality_display(a.quality)
                          if a.quality is not None else None),
        "quality_legend": quality_legend(quality),
        "removed_table": pd.DataFrame([r.__dict__ for r in a.outliers.removed]),
        "screening_columns": SCREENING_COLUMNS_TEXT.get(a.outliers.method, ""),
        "problems_table": pd.DataFrame([p.__dict__ for p in a.problems]),
        "methods": methods_table(a),
        "curve": curve_text(a) if a.ci_curve is not None else None,
        "ceiling_table": (pd.DataFrame(a.ceiling.summary()).T.rename_axis("statistic")
                          if "ceiling" in summary else None),
        "panel_table": (pd.DataFrame(answer_counts_rows(a.panel)) if a.panel is not None
                        else None),
        "screening_table": (pd.DataFrame(a.panel.screening).fillna("")
                            if a.panel is not None and a.panel.screening else None),
    }
    if a.reliability is not None:
        rel = a.reliability
        context["icc_table"] = pd.DataFrame(
            [{"ICC": k, "value": f"{v:.3f}",
              "95% CI": f"[{rel.icc_ci[k][0]:.3f}, {rel.icc_ci[k][1]:.3f}]"}
             for k, v in rel.icc.items()])
    path = out / "report.html"
    path.write_text(_environment().get_template("report.html").render(**context),
                    encoding="utf-8")
    return path
