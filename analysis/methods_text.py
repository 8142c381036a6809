"""The report's numbers as the paragraphs a paper's Methods and Results sections need: who
rated and who was left out (and by which rule), the score model and the DMOS with its
intervals, reliability and the human ceiling, and each metric against DMOS. Every number is
read from the report's own summary, so the text cannot disagree with the tables; where a part
was not computed its sentence is left out rather than guessed."""

from __future__ import annotations

import math
from typing import Any

from .metrics import CEILING_ROW
from .pipeline import Analysis

SCREENING_PROSE = {
    "p913": "raters whose ratings did not follow the others (correlation with the "
            "leave-one-out panel r1 < 0.75 and r2 < 0.8, ITU-T P.913) and whose P.910 MLE "
            "inconsistency was an outlier (robust z > 3.5) were removed, one at a time",
    "grubbs": "raters were screened with an iterative Grubbs test on each rater's mean "
              "absolute deviation from the panel, as in the CGVQM+D paper",
    "bt500": "raters were screened with the kurtosis-based procedure of ITU-R BT.500",
}
MODEL_PROSE = {
    "mle": "SUREAL's maximum-likelihood subject model (Li & Bampis 2020), which estimates "
           "each stimulus's quality together with each rater's bias and inconsistency and each "
           "content's ambiguity",
    "p910": "the ITU-T P.910 subject model (SUREAL's MLE_CO_AP2), which estimates each "
            "stimulus's quality together with each rater's bias and inconsistency",
    "mos": "plain mean opinion scores",
    "bt500": "plain means over the raters kept by ITU-R BT.500 rater rejection",
}


def _ci(value: float | None, low: float | None, high: float | None, digits: int = 3) -> str:
    if value is None or not math.isfinite(value):
        return "n/a"
    out = f"{value:.{digits}f}"
    if low is not None and high is not None and math.isfinite(low) and math.isfinite(high):
        out += f" [{low:.{digits}f}, {high:.{digits}f}]"
    return out


def _count(n: int, one: str, many: str | None = None) -> str:
    return f"{n} {one if n == 1 else (many or one + 's')}"


def _panel(a: Analysis, s: dict[str, Any]) -> str:
    rs = a.ratings
    kinds: dict[str, int] = {}
    for x in s["exclusions"]:
        kinds[x["kind"]] = kinds.get(x["kind"], 0) + 1
    text = (f"{_count(s['n_raters_input'], 'participant')} gave valid ratings of "
            f"{_count(s['n_stimuli'], 'stimulus', 'stimuli')} on a {rs.scale_min:g} to "
            f"{rs.scale_max:g} scale ({s['allocation']['sentence']}).")
    left = []
    if n := kinds.get("ended by vision check", 0) + kinds.get("failed vision check", 0):
        left.append(f"{_count(n, 'participant')} who failed the remote vision screening")
    if kinds.get("partial rater"):
        left.append(f"{_count(kinds['partial rater'], 'rater')} who answered less than "
                    f"{s['min_completeness']:.0%} of their trials")
    removed = len(s["removed_raters"])
    if s["outlier_method"] == "none":
        screening = " No rater screening was applied."
    else:
        prose = SCREENING_PROSE.get(s["outlier_method"], f"raters were screened "
                                                         f"({s['outlier_method']})")
        screening = (f" In the screening, {prose}: {_count(removed, 'rater')} "
                     f"{'was' if removed == 1 else 'were'} removed.")
    if left:
        text += " Not analysed: " + "; ".join(left) + "."
    return (text + screening + f" The analysis uses {_count(s['n_raters_used'], 'rater')} and "
            f"{s['n_ratings_used']} ratings.")


def _scores(a: Analysis, s: dict[str, Any]) -> str:
    model = MODEL_PROSE.get(a.config.model, s["model_name"])
    text = (f"Quality scores Q were estimated with {model}. DMOS = Q(v) - Q(ref) + "
            f"{a.screened.ref_score:g}, with Q(ref) the score of the hidden reference of the "
            f"same content; 95% confidence intervals come from {s['n_bootstrap']} bootstrap "
            "resamples of the raters.")
    if s.get("model_fallback"):
        text += f" {s['model_fallback']}"
    return text


def _reliability(s: dict[str, Any]) -> str:
    parts = []
    icc, ci = s.get("icc") or {}, s.get("icc_ci95") or {}
    if "ICC(2,k)" in icc:
        lo, hi = (ci.get("ICC(2,k)") or [None, None])
        lo1, hi1 = (ci.get("ICC(2,1)") or [None, None])
        how = "REML variance components" if "REML" in str(s.get("icc_method")) else \
            "a two-way random-effects ANOVA"
        n = (s.get("icc_counts") or {}).get("raters", s["n_raters_used"])
        parts.append(f"Inter-rater reliability over the {n} raters used was ICC(2,k) = "
                     f"{_ci(icc['ICC(2,k)'], lo, hi)} "
                     f"(single rater ICC(2,1) = {_ci(icc.get('ICC(2,1)'), lo1, hi1)}; "
                     f"computed from {how}, with 95% CIs)"
                     + (f", on the {s['icc_subset']}" if s.get("icc_subset") else "") + ".")
    c = s.get("ceiling")
    if c:
        p = c["plcc"]
        sb = (c.get("plcc_spearman_brown") or {}).get("median")
        parts.append(f"The human ceiling, half of the raters predicting the other half over "
                     f"{s['n_splits']} random splits, was PLCC = "
                     f"{_ci(p['median'], p['ci95_low'], p['ci95_high'])} (median and 95% "
                     "range)" + (f"; Spearman-Brown corrected to the full panel, {sb:.3f}"
                                 if sb is not None and math.isfinite(sb) else "") + ".")
    return " ".join(parts)


def _metric_line(m: dict[str, Any]) -> str:
    plcc = _ci(m.get("plcc"), m.get("plcc_ci95_low"), m.get("plcc_ci95_high"))
    srcc = _ci(m.get("srcc"), m.get("srcc_ci95_low"), m.get("srcc_ci95_high"))
    return f"{m['metric']}: PLCC {plcc}, SRCC {srcc}"


def _significance(s: dict[str, Any], names: list[str]) -> str:
    """Which metric's PLCC exceeds which, by the report's one-tailed paired bootstrap."""
    p_of, alpha = s.get("significance_p") or {}, s["alpha"]
    wins = [f"{a} over {b} (p = {p:.3g})" for a in names for b in names
            if a != b and (p := (p_of.get(a) or {}).get(b)) is not None and p < alpha]
    test = f"one-tailed paired bootstrap of the PLCC, alpha = {alpha:g}"
    if not wins:
        return f" No metric's PLCC was significantly higher than another's ({test})."
    return f" Significant differences ({test}, no correction for multiple comparisons): " \
        + "; ".join(wins) + "."


def _metrics(s: dict[str, Any]) -> str:
    rows = [m for m in s.get("metrics") or [] if m.get("plcc") is not None
            and m["metric"] != CEILING_ROW]  # the ceiling has its own sentence
    if not rows:
        return ""
    stimuli = _count(max(int(m["n"]) for m in rows), "distorted stimulus", "distorted stimuli")
    text = (f"Each metric was compared with DMOS on {stimuli} (hidden references excluded): "
            "PLCC after a 5-parameter logistic mapping, SRCC on the scores oriented so that higher "
            "is better, with 95% "
            "confidence intervals from a two-way bootstrap over raters and stimuli. "
            + "; ".join(_metric_line(m) for m in rows) + ".")
    if len(rows) > 1:
        text += _significance(s, [str(m["metric"]) for m in rows])
    return text


def methods_paragraphs(a: Analysis, s: dict[str, Any]) -> list[str]:
    """The paragraphs, from the analysis ``a`` and its summary ``s``
    (:func:`analysis.report.summary`)."""
    return [p for p in (_panel(a, s), _scores(a, s), _reliability(s), _metrics(s)) if p]
