"""The report folder: report.html, figures/*.png, dmos.csv, tables as CSV, summary.json.

The first screen of report.html says what went into the numbers and what did not: sessions
refused (another study, another manifest, withdrawn), copies of sessions, partial sessions
dropped or kept, raters removed by the screening and why, a model fallback, and metric scores
that do not come from the published metric.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .exports import write_dmos_csv, write_rating_matrix
from .figures import FIGURES, draw_all
from .mapping import MAPPING_FUNCTIONS
from .methods_text import methods_paragraphs
from .panel import panel_json
from .pilot_view import reversed_levels
from .pipeline import Analysis
from .presentation_text import pilot_raters, viewing_summary
from .quality import ALTERED_SESSION, THRESHOLDS
from .reliability import Reliability
from .report_html import write_html
from .screening import rules as screening_rules
from .screening.result import RemovedRater
from .sessions import withdrawn_participants
from .sureal_io import write_sureal_json
from .version import __version__

log = logging.getLogger(__name__)

SUMMARY_FORMAT = "cgvq-analysis-summary/3"
"""/3: everything but ``inputs`` (paths, command line) and ``run`` (timings) is the same for
the same input files and options, wherever they lie; /2 held the ``--sessions`` or
``--ratings`` paths as given (``source``) and the timings (``timings_s``) at the top."""

_QUALITY_COLUMNS = ("status", "sessions", "n_ratings", "n_planned", "completeness",
                    "timing_mode", "vsync", "preflight_skipped", "presentations",
                    "dropped_frames", "trials_with_drops", "requeued", "median_viewing_s",
                    "median_toggles", "minutes", "sittings", "screen", "refresh_hz",
                    "viewing_distance_cm",
                    "px_per_mm", "px_per_degree",
                    "hidden_ref_mean_share", "loo_r", "repeat_r", "vision", "flags")
#: The overall pairwise metric tests in summary.json (each on the stimuli both scored).
_PAIRWISE_COLUMNS = ("metric_a", "metric_b", "n", "plcc_a", "plcc_b", "boot_p", "boot_n",
                     "williams_p")


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


def ratings_per_stimulus(a: Analysis) -> dict[str, float]:
    """Min, median and max of the ratings each stimulus got, over the ratings the scores used."""
    counts = a.screened.ratings_per_stimulus()
    if counts.size == 0:
        return {"min": 0, "median": 0.0, "max": 0}
    return {"min": int(counts.min()), "median": float(np.median(counts)),
            "max": int(counts.max())}


_PLANNERS = {"server": "by the study server (uniformly until {warmup}, then from the DMOS "
                       "intervals)",
             "session": "uniformly by the app (no study server)"}


def _adaptive_words(settings: dict[str, Any] | None, planned_by: set[str]) -> str:
    """The adaptive settings in a few words (empty when unknown); ``planned_by``: who planned
    the later blocks, as the session files record it (empty: not known, e.g. from a CSV)."""
    if not settings:
        return ""
    n = settings.get("block_trials")
    size = (f"of {n} trial{'' if n == 1 else 's'}" if n else "as long as block 1")
    n_warm = settings.get("warmup_participants")
    warmup = (f"{n_warm} sessions had finished block 1" if n_warm else
              "its warm-up was done")
    if planned_by <= set(_PLANNERS) and planned_by:
        who = " planned " + " and some ".join(_PLANNERS[p].format(warmup=warmup)
                                               for p in sorted(planned_by))
    else:
        who = " planned by the study server (or uniformly by an app without one)"
    return (f"{settings.get('blocks')} blocks per session; block 1 holds every stimulus once, "
            f"later blocks {size}{who}, at most {settings.get('max_per_block')} of one "
            "stimulus per block")


def allocation_sentence(a: Analysis, counts: dict[str, float]) -> str:
    """How the ratings were allocated, in one sentence a paper can keep (the full design
    kept short)."""
    rs = a.screened
    per_cell = np.isfinite(rs.scores).sum(axis=2)
    lo, hi = counts["min"], counts["max"]
    spread = (f"each stimulus received {lo}" + ("" if lo == hi else f"-{hi}") +
              f" ratings (median {counts['median']:g})")
    if rs.allocation == "full":
        if per_cell.size and per_cell.min() == per_cell.max():
            r = int(per_cell.max())
            return (f"a full design: every rater rated every stimulus "
                    f"{'once' if r == 1 else f'{r} times'}")
        reps = rs.n_repetitions
        planned = f"{reps} repetition{'' if reps == 1 else 's'} planned"
        n_partial = len(a.partial_kept)
        why = (f"unbalanced by the {n_partial} partial session{'' if n_partial == 1 else 's'} "
               "kept" if n_partial else "unbalanced: not every rating was given as often")
        return f"a full design ({planned}), {why}: " + spread
    if rs.allocation == "adaptive":
        info = rs.rater_info
        planned_by = ({p.strip() for v in info["blocks_planned_by"].dropna() for p in
                       str(v).split(",") if p.strip()}
                      if info is not None and "blocks_planned_by" in info.columns else set())
        words = _adaptive_words(rs.allocation_settings, planned_by)
        return "an adaptive design" + (f" ({words})" if words else "") + ": " + spread
    return ("an unbalanced design (no allocation policy declared, but stimuli received "
            "different numbers of ratings): " + spread)


def allocation_summary(a: Analysis) -> dict[str, Any]:
    """The ``allocation`` block of summary.json: policy, settings, ratings per stimulus."""
    counts = ratings_per_stimulus(a)
    return {"policy": a.screened.allocation, "settings": a.screened.allocation_settings,
            "ratings_per_stimulus": counts, "sentence": allocation_sentence(a, counts)}


def _reliability_summary(rel: Reliability) -> dict[str, Any]:
    """The ICC keys of summary.json (with the subset they were computed on, if not all)."""
    out: dict[str, Any] = {
        "icc": {k: _num(v) for k, v in rel.icc.items()},
        "icc_ci95": {k: [_num(v[0]), _num(v[1])] for k, v in rel.icc_ci.items()},
        "icc_method": rel.method,
        "icc_subset": rel.subset or None,
        "icc_counts": {"stimuli": rel.n_stimuli, "raters": rel.n_raters,
                       "cells": rel.n_cells, "complete_stimuli": rel.n_targets},
    }
    if rel.complete_case:
        out["icc_complete_case"] = {
            "n_stimuli": rel.complete_case["n_stimuli"],
            "icc": {k: _num(v) for k, v in rel.complete_case["icc"].items()}}
    if rel.distorted_only:
        d = rel.distorted_only
        out["icc_distorted_only"] = {
            "n_stimuli": d["n_stimuli"], "icc": {k: _num(v) for k, v in d["icc"].items()},
            "icc_ci95": {k: [_num(v[0]), _num(v[1])] for k, v in d["ci"].items()}}
    out["intra_rater_mean_r"] = _num(rel.intra_rater.mean())
    return out


def _sessions_facts(a: Analysis, n_screened: int) -> dict[str, Any]:
    """Whether the screening could run on ``n_screened`` raters, the pilots among the raters
    used, and their minutes in the study."""
    rule = screening_rules().get(a.outliers.method)
    raters = list(a.screened.raters)
    return {"screening_applied": rule is None or n_screened >= rule.min_raters,
            "pilot_raters_used": pilot_raters(a.quality, raters),
            "withdrawn": withdrawn_participants(a.exclusions),
            "minutes": _minutes(a.quality, raters)}


def _minutes(quality: pd.DataFrame | None, raters: list[str]) -> dict[str, Any] | None:
    """The used raters' minutes in the study (session files only): median and range.
    Simulated raters (``cgvq-study simulate``) spent no time: they are not counted (a
    "median 0.0 min" reads as a fact about participants)."""
    if quality is None or "minutes" not in quality.columns:
        return None
    q = quality.reindex(raters)
    if "timing_mode" in q.columns:
        q = q[~q["timing_mode"].astype(str).str.contains("simulated")]
    m = pd.to_numeric(q["minutes"], errors="coerce").dropna()
    if not len(m):
        return None
    return {"n": len(m), "median": float(m.median()), "min": float(m.min()),
            "max": float(m.max())}


ENVIRONMENT = ("sureal", "numpy", "scipy", "pandas", "pingouin", "matplotlib")
"""The libraries whose versions can change a number of the report."""


def environment() -> dict[str, str]:
    """Python's and :data:`ENVIRONMENT`'s versions, as installed where the report was made."""
    import platform
    from importlib import metadata

    out = {"python": platform.python_version()}
    for name in ENVIRONMENT:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def summary(a: Analysis) -> dict[str, Any]:
    """Machine-readable results (the demo and scripts read ``summary.json``)."""
    rs, sc = a.screened, a.scores
    used = a.used or rs
    out: dict[str, Any] = {
        "format": SUMMARY_FORMAT,
        "study": rs.study,
        "model": sc.model,
        "model_name": sc.model_name,
        "model_fallback": sc.fallback,
        "outlier_method": a.outliers.method,
        "screening_subset": a.outliers.subset or None,
        "allocation": allocation_summary(a),
        "min_completeness": a.config.min_completeness,
        "alpha": a.config.alpha,
        "seed": a.config.seed,
        "n_bootstrap": a.config.n_boot,
        "n_splits": a.config.n_splits,
        "scale": {"min": a.ratings.scale_min, "max": a.ratings.scale_max,
                  "direction": a.ratings.scale_direction,
                  "mirrored": a.ratings.scale_direction == "lower_is_better",
                  "labels": [{"position": p, "text": t} for p, t in a.ratings.scale_labels],
                  "question": a.ratings.scale_question or None},
        "n_raters_input": a.ratings.n_raters,
        "n_raters_after_completeness": used.n_raters,
        "n_raters_used": rs.n_raters,
        "n_stimuli": rs.n_stimuli,
        "n_ratings_used": rs.n_ratings,
        "exclusions": [x.__dict__ for x in a.exclusions],
        "partial_kept": [{"rater": r, "completeness": c} for r, c in a.partial_kept],
        "altered_kept": [{"rater": r, "altered": where} for r, where in a.altered_kept],
        "removed_raters": [{k: _num(v) for k, v in r.__dict__.items()}
                           for r in a.outliers.removed],
        "screening": _records(a.outliers.table, index="rater"),
        "model_rejected_raters": list(sc.rejected),
        **_sessions_facts(a, used.n_raters),
        "data_quality": _records(a.quality.reindex(columns=list(_QUALITY_COLUMNS))
                                 if a.quality is not None else None, index="rater"),
        "flag_thresholds": THRESHOLDS,
        "n_input_problems": len(a.problems),
        "reversed_levels": reversed_levels(a.dmos(), a.ratings.scale_max - a.ratings.scale_min),
        "run": {"timings_s": {k: round(v, 3) for k, v in a.timings.items()}},
    }
    if a.reliability is not None:
        out.update(_reliability_summary(a.reliability))
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
    if a.panel is not None:
        out["panel"] = panel_json(a.panel)
    if a.metrics is not None:
        out.update(_metrics_summary(a, a.metrics))
    return out


def _metrics_summary(a: Analysis, m: Any) -> dict[str, Any]:
    """The metric part of :func:`summary`: the tables, flags, each metric's provenance and
    fitted mapping, the viewing conditions and the pairwise tests."""
    overall = (m.comparisons[m.comparisons["scope"] == "all"]
               if len(m.comparisons) else m.comparisons)
    directions = dict(zip(m.table["metric"], m.table["direction"], strict=True))
    return {
        "metrics": _records(m.table),
        "metrics_per_method": _records(m.per_method),
        "untrained_backbone": dict(m.untrained),
        "metric_doubts": dict(m.suspect),
        "metric_provenance": dict(m.provenance),
        "metric_titles": {name: m.title(name) for name in m.mappings},
        "metric_mappings": {
            name: {"kind": mp.kind, "function": MAPPING_FUNCTIONS[mp.kind],
                   "sign": -1 if directions.get(name) == "lower-better" else 1,
                   "center": mp.center, "scale": mp.scale, "params": list(mp.params)}
            for name, mp in m.mappings.items()},
        "not_applicable": dict(m.not_applicable),
        "viewing": viewing_summary(a.ratings, a.quality, list(a.screened.raters), m.ppd),
        "significance_p": {r: {c: _num(m.significance.loc[r, c])
                               for c in m.significance.columns}
                           for r in m.significance.index},
        "williams_p": {r: {c: _num(m.williams.loc[r, c]) for c in m.williams.columns}
                       for r in m.williams.index},
        "pairwise": _records(overall.reindex(columns=list(_PAIRWISE_COLUMNS))
                             if len(overall) else None),
    }


def summary_text(a: Analysis) -> str:
    """A short terminal summary."""
    s = summary(a)
    lines = [f"study {s['study']}: {s['n_stimuli']} stimuli, {s['n_raters_used']} of "
             f"{s['n_raters_input']} raters, {s['n_ratings_used']} ratings; model "
             f"{s['model_name']}"]
    design = s["allocation"]["sentence"]
    lines.append(design[0].upper() + design[1:] + ".")
    if s["model_fallback"]:
        lines.append(f"WARNING: {s['model_fallback']}")
    lines += [f"WARNING: {h}" for h in s["reversed_levels"]]
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
    altered = [x for x in s["exclusions"] if x["kind"] == ALTERED_SESSION]
    if altered or s["altered_kept"]:
        lines.append("session files altered outside the app (only the ratings before the "
                     "change used): " + ", ".join(
                         [f"{x['who']} (left out: too few)" for x in altered]
                         + [f"{p['rater']} (kept)" for p in s["altered_kept"]]))
    pilots = [x for x in s["exclusions"] if x["kind"] == "pilot session"]
    if pilots:
        lines.append("pilot sessions left out (paced without vsync; --include-pilots keeps "
                     "them): " + ", ".join(Path(x["who"]).name for x in pilots))
    if s["minutes"]:
        m = s["minutes"]
        lines.append(f"time in the study: median {m['median']:.1f} min ({m['min']:.1f}-"
                     f"{m['max']:.1f}) over {m['n']} rater(s)")
    if s["pilot_raters_used"]:
        lines.append("pilots used (paced without vsync, not participant data): "
                     + ", ".join(s["pilot_raters_used"]))
    if not s["screening_applied"]:
        lines.append(f"rater screening ({s['outlier_method']}): not applied, it needs at "
                     "least 3 raters")
    else:
        lines.append(f"removed raters ({s['outlier_method']}): "
                     + (", ".join(r["rater"] for r in s["removed_raters"]) or "none")
                     + (f"; screened on the {s['screening_subset']}"
                        if s["screening_subset"] else ""))
    if s["model_rejected_raters"]:
        lines.append(f"rejected by the score model (--model {s['model']}), left out of every "
                     "number: " + ", ".join(map(str, s["model_rejected_raters"])))
    if "icc" in s:
        lines.append(f"ICC(2,k) {s['icc']['ICC(2,k)']:.3f}   ICC(3,k) {s['icc']['ICC(3,k)']:.3f}"
                     + ("   (REML, unbalanced)" if "REML" in s["icc_method"] else "")
                     + (f"   on the {s['icc_subset']}" if s["icc_subset"] else ""))
    if "ceiling" in s:
        c = s["ceiling"]["plcc"]
        bound = (s["ceiling"].get("plcc_full_panel_bound") or {}).get("median")
        lines.append(f"two half panels' agreement (split-half PLCC) {c['median']:.3f} "
                     f"[{c['p2_5']:.3f}, {c['p97_5']:.3f}]"
                     + (f"; the ceiling for a metric against the full panel {bound:.3f}"
                        if bound is not None else ""))
    if "metrics" in s:
        width = max(32, *(len(str(m["metric"])) for m in s["metrics"]))
        lines.append(f"{'metric':{width}s} {'n':>4s} {'PLCC':>7s} {'SRCC':>7s} {'KRCC':>7s} "
                     f"{'RMSE':>8s} {'RMSE*':>8s}")
        for m in s["metrics"]:
            vals = [m.get(k) for k in ("plcc", "srcc", "krcc")]
            txt = " ".join(f"{v:7.3f}" if v is not None else "    n/a" for v in vals)
            rm = [m.get(k) for k in ("rmse", "rmse_star")]
            txt += " " + " ".join(f"{v:8.3f}" if v is not None else "     n/a" for v in rm)
            lines.append(f"{m['metric']!s:{width}s} {m['n']:4d} {txt}")
        for name, why in s.get("untrained_backbone", {}).items():
            lines.append(f"WARNING: {name}: {why}; not the published metric")
        for name, why in s.get("metric_doubts", {}).items():
            lines.append(f"WARNING: {name}: {why}")
    if s["n_input_problems"]:
        lines.append(f"{s['n_input_problems']} input problem(s) found; see tables/problems.csv")
    return "\n".join(lines)


def write_tables(a: Analysis, out: Path) -> dict[str, Path]:
    """Every table of the report as CSV."""
    t: dict[str, pd.DataFrame] = {}
    t["exclusions"] = pd.DataFrame([x.__dict__ for x in a.exclusions],
                                   columns=["kind", "who", "reason", "rule"])
    t["outliers"] = pd.DataFrame([r.__dict__ for r in a.outliers.removed],
                                 columns=list(RemovedRater.COLUMNS))
    if a.outliers.table is not None:
        t["screening"] = a.outliers.table.reset_index()
    if a.quality is not None:
        t["data_quality"] = a.quality.reset_index()
    if a.reliability is not None:
        rel = a.reliability
        rows = [{"type": k, "icc": v, "ci95_low": rel.icc_ci[k][0],
                 "ci95_high": rel.icc_ci[k][1], "method": rel.method,
                 "n_stimuli": rel.n_stimuli, "n_raters": rel.n_raters,
                 "subset": rel.subset or "all ratings"}
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
    unknown = set(t) - set(TABLE_NAMES)
    assert not unknown, f"add {unknown} to TABLE_NAMES (a rerun removes only those)"
    paths = {}
    (out / "tables").mkdir(parents=True, exist_ok=True)
    for name, frame in t.items():
        path = out / "tables" / f"{name}.csv"
        keep_index = name in ("inter_rater", "ceiling", "significance_p", "williams_p")
        frame.to_csv(path, index=keep_index)
        paths[name] = path
    return paths


TABLE_NAMES = ("exclusions", "outliers", "screening", "data_quality", "icc", "inter_rater",
               "intra_rater", "raters", "content_ambiguity", "ceiling", "ci_vs_raters",
               "metrics", "metrics_per_method", "significance_p", "williams_p", "comparisons",
               "problems")
"""Every table a report can write (``tables/<name>.csv``); a rerun removes them all first."""


def write_report(a: Analysis, out: str | Path, *, notes: str | None = None,
                 inputs: dict[str, Any] | None = None) -> Path:
    """Write the full report folder and return the path of report.html. ``inputs``: where
    the numbers came from (files with their sha256, the command), kept in summary.json and
    shown under the title, so that a table copied into a paper can be traced back."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # report.html and summary.json say the folder is finished: an earlier run's go first and
    # come back last, so an interrupted rerun never leaves them beside newer tables.
    for finished in ("report.html", "summary.json"):
        (out / finished).unlink(missing_ok=True)
    # An earlier run's tables and figures go too: one this run does not write (no --metric
    # now) would otherwise pass for part of this report.
    for name in TABLE_NAMES:
        (out / "tables" / f"{name}.csv").unlink(missing_ok=True)
    for name in FIGURES:
        for suffix in (".png", ".pdf"):
            (out / "figures" / f"{name}{suffix}").unlink(missing_ok=True)
    write_dmos_csv(a.screened, a.scores, out / "dmos.csv")
    write_sureal_json(a.ratings, out / "sureal_dataset.json")
    write_rating_matrix(a.ratings, out / "rating_matrix_p910.csv")
    write_tables(a, out)
    figures = draw_all(a, out / "figures")
    facts = summary(a)
    facts["inputs"] = {"tool_version": __version__, "environment": environment(),
                       **(inputs or {})}
    (out / "methods.txt").write_text("\n\n".join(methods_paragraphs(a, facts)) + "\n",
                                     encoding="utf-8")
    (out / "summary.json").write_text(json.dumps(facts, indent=1, default=_num),
                                      encoding="utf-8")
    return write_html(a, out, figures, facts, notes)
