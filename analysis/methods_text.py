"""The report's numbers as the paragraphs a paper's Methods and Results sections need: who
rated and who was left out (and by which rule), the score model and the DMOS with its
intervals, reliability and the human ceiling, and each metric against DMOS. Every number is
read from the report's own summary, so the text cannot disagree with the tables; where a part
was not computed its sentence is left out rather than guessed."""

from __future__ import annotations

import math
from typing import Any

from .intervals import MIN_RATERS_FOR_INTERVAL
from .metrics import CEILING_ROW
from .pipeline import MODEL_REJECTION, Analysis
from .presentation_text import metric_viewing_text, presentation_paragraph
from .quality import ALTERED_SESSION
from .references import cited

SCREENING_PROSE = {
    "p913": "Raters were screened one at a time (ITU-T P.913, iterated): a rater was removed "
            "only when both tests failed, their ratings did not follow the others ({rule}) "
            "and their P.910 MLE inconsistency was an outlier (robust z > 3.5)",
    "grubbs": "Raters were screened with an iterative Grubbs test on each rater's mean "
              "absolute deviation from the panel, as in the CGVQM+D paper",
    "bt500": "Raters were screened with the kurtosis-based procedure of ITU-R BT.500 (a vote "
             "is outside when it lies beyond 2 s.d. of the stimulus's ratings, 4.47 s.d. for "
             "non-normal ones; a rater is rejected when more than 5% of their votes are "
             "outside and those are not mostly on one side, |P-Q|/(P+Q) < 0.3)",
}
P913_RULES = {True: "correlation with the leave-one-out panel r1 < 0.75 and, on per-HRC "
                    "means, r2 < 0.8",
              False: "correlation with the leave-one-out panel r1 < 0.75; the second test, "
                     "r2 on per-HRC means, needs 4 HRCs and could not be applied, so r1 "
                     "decided alone"}
MODEL_PROSE = {
    "mle": "SUREAL's maximum-likelihood subject model (Li et al. 2020), which estimates "
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
    out = fixed(value, digits)
    if low is not None and high is not None and math.isfinite(low) and math.isfinite(high):
        out += f" [{fixed(low, digits)}, {fixed(high, digits)}]"
    return out


def fixed(x: float, digits: int = 3) -> str:
    """``x`` with ``digits`` decimals, never "-0.000"."""
    out = f"{x:.{digits}f}"
    return out[1:] if out.startswith("-") and not out.strip("-0.") else out


def p_text(p: float, n_resamples: int | None = None) -> str:
    """A p value as a paper gives it: three decimals, and "p < 0.001" below that. At the
    floor of a bootstrap p of ``n_resamples`` (no resample contradicted: 1/(B + 1)) it is a
    bound, "p ≤ 0.001" for B = 999 as for B = 1000 (one outcome, one wording)."""
    if n_resamples and p <= 1 / (n_resamples + 1) + 1e-12:
        return f"p ≤ {math.ceil(1000 / (n_resamples + 1) - 1e-9) / 1000:.3f}"
    return "p < 0.001" if p < 0.001 - 1e-12 else f"p = {p:.3f}"


def _count(n: int, one: str, many: str | None = None) -> str:
    return f"{n} {one if n == 1 else (many or one + 's')}"


def _names(names: list[str]) -> str:
    return ", ".join(map(str, names[:8])) + (f" and {len(names) - 8} more" if len(names) > 8
                                             else "")


def _and(items: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``: a list as prose joins it."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _design(a: Analysis) -> str:
    """Source contents, distortion conditions (HRCs) and hidden references, counted."""
    st = a.screened.stimuli
    hidden = st["is_hidden_reference"].astype(bool)
    dist = st[~hidden]
    if dist["level"].isna().all():  # a SUREAL dataset names no method or level
        return "; ".join([_count(st["reference"].nunique(), "source content"),
                          _count(len(dist), "distorted version"),
                          _count(int(hidden.sum()), "hidden reference")])
    hrcs = dist[["method", "level"]].drop_duplicates()
    methods = [m.replace("_", " ") for m in dict.fromkeys(dist["method"].astype(str))]
    n_src = st["reference"].nunique()
    parts = [_count(n_src, "source content"),
             _count(len(hrcs), "distortion condition") + (
                 f": {_names(methods)} at {_count(dist['level'].nunique(), 'level')}"
                 if len(methods) else "")]
    sources = dist.groupby(["method", "level"])["reference"].nunique()
    crossed = ("" if len(dist) >= len(hrcs) * n_src else
               f", each condition applied to {int(sources.min())}" + (
                   "" if sources.min() == sources.max() else f"-{int(sources.max())}")
               + f" of the {n_src} source contents")
    parts.append(_count(len(dist), "processed sequence") + crossed)
    parts.append(_count(int(hidden.sum()), "hidden reference") if hidden.any() else
                 "no hidden reference")
    return "; ".join(parts)


def _scale(a: Analysis) -> str:
    """The scale as the participants saw it: range, labels, and the mirroring of an impairment
    scale (every number in the report is on the mirrored, higher-is-better scale)."""
    rs = a.ratings
    lo, hi = f"{rs.scale_min:g}", f"{rs.scale_max:g}"
    mirrored = rs.scale_direction == "lower_is_better"
    labels = rs.scale_labels  # where the participants saw them
    text = f"a{' continuous' if labels else ''} {lo} to {hi} scale"
    if mirrored:
        text += ", on which lower meant better,"
    if labels:
        text += " labelled " + ", ".join(f'"{t}" ({p:g})' for p, t in labels)
        if rs.scale_question:
            text += f', under the question "{rs.scale_question}"'
    return text.rstrip(",")


def _mirror_note(a: Analysis) -> str:
    rs = a.ratings
    if rs.scale_direction != "lower_is_better":
        return ""
    return (f" Before the analysis every rating x was mirrored to {rs.scale_min:g} + "
            f"{rs.scale_max:g} - x, so that higher is better: all scores below, MOS included, "
            "are on the mirrored scale.")


def _screening(a: Analysis, s: dict[str, Any]) -> str:
    removed = [str(r["rater"]) for r in s["removed_raters"]]
    if s["outlier_method"] == "none":
        return " No rater screening was applied."
    if not s.get("screening_applied", True):
        return (f" The rater screening ({s['outlier_method']}) needs at least 3 raters and "
                "was not applied: no rater was removed.")
    prose = SCREENING_PROSE.get(s["outlier_method"], f"Raters were screened "
                                                     f"({s['outlier_method']})")
    if s["outlier_method"] == "p913":
        has_r2 = any(r.get("r2") is not None for r in s["screening"])
        prose = prose.replace("{rule}", P913_RULES[has_r2])
    who = f" ({_names(removed)})" if removed else ""
    text = (f" {prose}: {_count(len(removed), 'rater')}{who} "
            f"{'was' if len(removed) == 1 else 'were'} removed." if removed else
            f" {prose}: no rater was removed.")
    near = [str(r["rater"]) for r in s["screening"]
            if str(r.get("reason") or "").startswith("near-miss")]
    if near:
        text += (f" {_count(len(near), 'rater')} close to the rule "
                 f"{'was' if len(near) == 1 else 'were'} kept ({_names(near)}).")
    return text


def _panel(a: Analysis, s: dict[str, Any]) -> str:
    kinds: dict[str, list[str]] = {}
    for x in s["exclusions"]:
        kinds.setdefault(x["kind"], []).append(str(x["who"]))
    n_in, withdrawn = s["n_raters_input"], s.get("withdrawn") or []
    start = (f"{_count(n_in + len(withdrawn), 'participant')} took part and "
             f"{len(withdrawn)} withdrew (none of their ratings or answers was used); the "
             f"other {n_in} gave valid ratings" if withdrawn else
             f"{_count(n_in, 'participant')} gave valid ratings")
    text = (f"{start}. The study had {_count(s['n_stimuli'], 'stimulus', 'stimuli')} "
            f"({_design(a)}), rated on {_scale(a)}; {s['allocation']['sentence']}."
            f"{_mirror_note(a)}")
    left = []
    if n := len(kinds.get("ended by vision check", [])) + len(kinds.get("failed vision check",
                                                                       [])):
        left.append(f"{_count(n, 'participant')} who failed the remote vision screening")
    if kinds.get("partial rater"):
        left.append(f"{_count(len(kinds['partial rater']), 'rater')} who answered less than "
                    f"{s['min_completeness']:.0%} of their trials")
    if altered := kinds.get(ALTERED_SESSION):
        left.append(f"{_count(len(altered), 'rater')} whose session file was altered after "
                    f"it was recorded ({_names(altered)}), leaving less than "
                    f"{s['min_completeness']:.0%} of their trials with intact records")
    if left:
        text += " Not analysed: " + "; ".join(left) + "."
    if s["partial_kept"]:
        kept = [f"{p['rater']}, {percent(p['completeness'])}" for p in s["partial_kept"]]
        text += (f" {_count(len(kept), 'rater')} with an incomplete session "
                 f"{'was' if len(kept) == 1 else 'were'} kept ({'; '.join(kept[:8])}).")
    if kept := s.get("altered_kept"):
        text += (f" {_count(len(kept), 'rater')} whose session file was altered after it was "
                 f"recorded {'was' if len(kept) == 1 else 'were'} kept with the ratings "
                 "recorded before the change ("
                 + "; ".join(f"{p['rater']}: {p['altered']}" for p in kept) + ").")
    text += _screening(a, s)
    if rejected := kinds.get(MODEL_REJECTION):
        text += (f" ITU-R BT.500 rater rejection inside the score model removed "
                 f"{_count(len(rejected), 'rater')} ({_names(rejected)}).")
    text += (f" The analysis uses {_count(s['n_raters_used'], 'rater')} and "
             f"{s['n_ratings_used']} ratings.")
    if sentence := (s.get("panel") or {}).get("sentence"):  # from their questionnaires
        text += f" The raters analysed were {sentence}"
    return text


def percent(share: float) -> str:
    """A share as a percentage that never rounds an incomplete session up to "100%" (or a
    tiny share down to "0%")."""
    out = f"{share:.0%}"
    if (out == "100%" and share < 1) or (out == "0%" and share > 0):
        out = f"{share:.1%}"
    return out


def _scores(a: Analysis, s: dict[str, Any]) -> str:
    model = MODEL_PROSE.get(a.config.model, s["model_name"])
    rs = a.screened
    refs = rs.reference_index()
    has = refs >= 0
    estimator = ("plain means" if a.config.model in ("mos", "bt500") else
                 "the model's rater bias and inconsistency held fixed")
    ci = (f"95% confidence intervals are t intervals (Kish's effective number of raters "
          f"minus 1 degrees of freedom) whose standard deviation comes from "
          f"{s['n_bootstrap']} bootstrap resamples of the raters ({estimator}), scaled by "
          "sqrt(n/(n-1)) for the n raters behind the stimulus.")
    text = f"Quality scores Q were estimated with {model}."
    if not has.any():
        text += (" No hidden reference was rated, so no DMOS was formed: the scores reported "
                 "in the DMOS column are the quality estimates Q(v) themselves, on the rating "
                 "scale. " + ci.replace("95% confidence", "Their 95% confidence"))
    else:
        text += (f" DMOS = Q(v) - Q(ref) + {a.screened.ref_score:g}, with Q(ref) the score of "
                 "the hidden reference of the same content (its reference shown against "
                 "itself): the differential score of ITU-T P.910's ACR-HR, applied here to "
                 "remove, per content, how far below the top of the scale raters put even an "
                 f"unimpaired video; {ci}")
        if not has.all():
            missing = sorted(set(rs.stimuli["reference"].astype(str).to_numpy()[~has]))
            text += (f" No hidden reference of {_names(missing)} was rated: "
                     f"{_count(int((~has).sum()), 'stimulus', 'stimuli')} of "
                     f"{'that content have' if len(missing) == 1 else 'those contents have'} "
                     "no DMOS and are left out of the metric comparison.")
    text += _without_interval(a)
    if s.get("model_fallback"):
        text += f" {s['model_fallback']}"
    return text


def _without_interval(a: Analysis) -> str:
    """The DMOS given without an interval because too few raters stand behind them."""
    d = a.dmos()
    cond = ~d["is_hidden_reference"].astype(bool) & d["dmos"].notna()
    n = int((cond & d["ci95_low"].isna()).sum())
    if not n:
        return ""
    why = (f"fewer than {MIN_RATERS_FOR_INTERVAL} raters (a bootstrap over two raters has "
           "three outcomes, and its t quantile of 12.7 spans the scale)")
    if n == int(cond.sum()):
        return f" No DMOS has an interval: every stimulus was rated, with its reference, by {why}."
    return (f" {_count(n, 'stimulus', 'stimuli')} {'has' if n == 1 else 'have'} no DMOS "
            f"interval: rated, with {'its' if n == 1 else 'their'} reference, by {why}.")


def _reliability(a: Analysis, s: dict[str, Any]) -> str:
    parts = []
    icc, ci = s.get("icc") or {}, s.get("icc_ci95") or {}
    if "ICC(2,k)" in icc:
        lo, hi = (ci.get("ICC(2,k)") or [None, None])
        lo1, hi1 = (ci.get("ICC(2,1)") or [None, None])
        how = "REML variance components" if "REML" in str(s.get("icc_method")) else \
            "a two-way random-effects ANOVA (absolute agreement)"
        counts = s.get("icc_counts") or {}
        n = counts.get("raters", s["n_raters_used"])
        n_hidden = int(a.screened.hidden_reference_mask.sum())
        targets = _count(int(counts.get("stimuli", s["n_stimuli"])), "stimulus", "stimuli") + (
            f" ({_count(n_hidden, 'hidden reference')} among them)" if n_hidden else "")
        basis = (f"the {s['icc_subset']}" if s.get("icc_subset") else
                 "each rater's mean over repetitions")
        parts.append(f"Inter-rater reliability over the {n} raters used and {targets} was "
                     f"ICC(2,k) = {_ci(icc['ICC(2,k)'], lo, hi)} "
                     f"(single rater ICC(2,1) = {_ci(icc.get('ICC(2,1)'), lo1, hi1)}; "
                     f"computed from {how} on {basis}, with 95% CIs).")
        if d := s.get("icc_distorted_only"):
            dci = d["icc_ci95"]
            which = ", the ones the metrics are compared on," if s.get("metrics") else ""
            parts[-1] += (f" On the {d['n_stimuli']} distorted stimuli alone{which} "
                          f"ICC(2,k) = "
                          f"{_ci(d['icc'].get('ICC(2,k)'), *(dci.get('ICC(2,k)') or [None] * 2))}"
                          f" and ICC(2,1) = "
                          f"{_ci(d['icc'].get('ICC(2,1)'), *(dci.get('ICC(2,1)') or [None] * 2))}"
                          ".")
    c = s.get("ceiling")
    if c:
        p = c["plcc"]
        parts.append(f"Two halves of the raters agreed with PLCC = "
                     f"{_ci(p['median'], p['p2_5'], p['p97_5'])} (median and 2.5-97.5 "
                     f"percentiles of {s['n_splits']} random splits, plain-mean DMOS of the "
                     "distorted stimuli).")
        sb = (c.get("plcc_spearman_brown") or {}).get("median")
        bound = (c.get("plcc_full_panel_bound") or {}).get("median")
        if sb is not None and math.isfinite(sb):
            sentence = (f" Projected to the full panel (Spearman-Brown), the DMOS's "
                        f"reliability is {sb:.3f}")
            if bound is not None and math.isfinite(bound):
                sentence += (f"; a metric that predicted the true quality exactly would reach "
                             f"a PLCC of about {bound:.3f} (its square root) against this "
                             "DMOS: the human ceiling for a metric (the half-panel agreement "
                             "understates it)")
            parts[-1] += sentence + "."
    return " ".join(parts)


def _title(s: dict[str, Any], name: str) -> str:
    """A metric's name in prose: its title (``PSNR``, ``CGVQM-2``) where the scores gave one."""
    return str((s.get("metric_titles") or {}).get(name, name))


def _metric_line(s: dict[str, Any], m: dict[str, Any], n_max: int) -> str:
    plcc = _ci(m.get("plcc"), m.get("plcc_ci95_low"), m.get("plcc_ci95_high"))
    srcc = _ci(m.get("srcc"), m.get("srcc_ci95_low"), m.get("srcc_ci95_high"))
    rmse = _ci(m.get("rmse"), m.get("rmse_ci95_low"), m.get("rmse_ci95_high"), digits=2)
    notes = []
    if int(m["n"]) != n_max:
        notes.append(f"{m['n']} of the {n_max} stimuli scored")
    if m.get("fit") != "logistic5":
        notes.append("mapped with a straight line: too few stimuli, or no logistic fit")
    name = _title(s, str(m["metric"])) + (f" ({'; '.join(notes)})" if notes else "")
    return f"{name}: PLCC {plcc}, SRCC {srcc}, RMSE {rmse}"


def _significance(s: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    """Which metric's PLCC exceeds which, by the report's one-tailed paired bootstrap (on the
    stimuli both metrics scored)."""
    alpha = s["alpha"]
    n_of = {str(m["metric"]): int(m["n"]) for m in rows}
    wins, subsets = [], False
    doubt = s.get("metric_doubts") or {}
    for c in s.get("pairwise") or []:
        a, b, p = str(c["metric_a"]), str(c["metric_b"]), c.get("boot_p")
        if a not in n_of or b not in n_of or p is None or not p < alpha:
            continue
        if a in doubt or b in doubt:  # a win of a metric read the wrong way round is none
            continue
        shared = int(c["n"])
        where = f"; on the {shared} stimuli both scored" if shared != max(n_of[a],
                                                                          n_of[b]) else ""
        subsets |= bool(where)
        shown = p_text(p, c.get("boot_n"))
        wins.append(f"{_title(s, a)} over {_title(s, b)} ({shown}{where})")
    test = f"one-tailed paired bootstrap of the PLCC, alpha = {alpha:g}"
    if subsets or len(set(n_of.values())) > 1:
        test += ", each pair on the stimuli both metrics scored"
    left = [_title(s, m) for m in n_of if m in doubt]
    aside = f"; {_and(left)} left out, see the note above" if left else ""
    if not wins:
        return f" No metric's PLCC was significantly higher than another's ({test}{aside})."
    return f" Significant differences ({test}, no correction for multiple comparisons{aside}): " \
        + "; ".join(wins) + "."


def _implementations(s: dict[str, Any], names: list[str]) -> str:
    """Which implementation (and version) computed each metric, as its score rows record it;
    metrics sharing one are named together."""
    groups: dict[str, list[str]] = {}
    unrecorded = []
    for name in names:
        versions = (s.get("metric_provenance") or {}).get(name, {}).get("versions") or []
        words = "; ".join(", ".join(f"{v}" if k == "implementation" else f"{k} {v}"
                                    for k, v in entry.items()) if isinstance(entry, dict)
                          else str(entry) for entry in versions)
        if words:
            groups.setdefault(words, []).append(_title(s, name))
        else:
            unrecorded.append(_title(s, name))
    if not groups:
        return ""
    return " Implementations: " + "; ".join(
        f"{_and(metrics)}: {words}" for words, metrics in groups.items()) + (
        f"; {_and(unrecorded)}: not recorded in {'its' if len(unrecorded) == 1 else 'their'} "
        "scores (name the implementation and version)" if unrecorded else "") + "."


def _metrics(s: dict[str, Any]) -> str:
    rows = [m for m in s.get("metrics") or [] if m.get("plcc") is not None
            and m["metric"] != CEILING_ROW]  # the ceiling has its own sentence
    if not rows:
        return ""
    n_max = max(int(m["n"]) for m in rows)
    stimuli = _count(n_max, "distorted stimulus", "distorted stimuli")
    same = all(int(m["n"]) == n_max for m in rows)
    text = (f"Each metric was compared with DMOS on {'the ' if same else 'up to '}{stimuli} "
            "(hidden references excluded): PLCC and RMSE (ITU-T P.1401, N - d degrees of "
            "freedom) after a 5-parameter logistic mapping, SRCC on the scores oriented so that "
            "higher is better, with 95% confidence intervals from a two-way bootstrap over "
            f"raters and stimuli ({s['n_bootstrap']} resamples, mapping refitted in each). "
            + "; ".join(_metric_line(s, m, n_max) for m in rows) + ".")
    if len(rows) > 1:
        text += _significance(s, rows)
    text += (" KRCC, RMSE* (P.1401's epsilon-insensitive RMSE) and the outlier ratio are in "
             "the report's metric table" + (", and Williams' t and Steiger's Z for each pair of "
                                            "metrics in its tables/comparisons.csv"
                                            if len(rows) > 1 else "") + ".")
    text += _implementations(s, [str(m["metric"]) for m in rows])
    if any(mp.get("kind") == "logistic5" for mp in (s.get("metric_mappings") or {}).values()):
        negated = any(m.get("direction") == "lower-better" for m in rows)
        text += (" The mapping was DMOS = b1 (1/2 - 1/(1 + exp(b2 (z - b3)))) + b4 z + b5 on "
                 "the score standardised by its median and standard deviation (z"
                 + ("; a lower-better score negated first" if negated else "") + "); each "
                 "metric's fitted parameters are in the report's summary.json.")
    viewing, _ = metric_viewing_text(s.get("viewing"), s.get("metric_titles"))
    return text + (" " + viewing if viewing else "")


def methods_paragraphs(a: Analysis, s: dict[str, Any]) -> list[str]:
    """The paragraphs, from the analysis ``a`` and its summary ``s``
    (:func:`analysis.report.summary`)."""
    shown = presentation_paragraph(a.ratings, a.quality, list(a.screened.raters))
    pilots = s.get("pilot_raters_used") or []
    warning = (f"[Not for a paper as it stands: {len(pilots)} of the {s['n_raters_used']} "
               f"raters ran pilots, paced without vsync ({_names(pilots)}); they are not "
               "participant data.]" if pilots else "")
    flagged = s.get("untrained_backbone") or {}
    if flagged:  # what a paper could paste must not pass for the published metric
        warning = " ".join(filter(None, [warning, "[Not the published metric: " + "; ".join(
            f"{_title(s, name)} ran with {why}" for name, why in flagged.items())
            + (". Its numbers here are not those of the metric it is named after.]"
               if len(flagged) == 1 else
               ". Their numbers here are not those of the metrics they are named after.]")]))
    doubts = s.get("metric_doubts") or {}
    if doubts:  # a reversed direction reads as a good metric: never pasted unnoticed
        warning = " ".join(filter(None, [warning, "[Check before use: " + "; ".join(
            f"{_title(s, name)}: {why}" for name, why in doubts.items())
            + (". Comparisons with it are" if len(doubts) == 1 else ". Comparisons with them are")
            + " left out of this text.]"]))
    todo = ("[To add, which no file records: the room and its lighting; how the ethics "
            "approval and the participants' informed consent were obtained; the "
            "compensation.]" if shown else "")
    body = [p for p in (warning, _panel(a, s), shown, _scores(a, s), _reliability(a, s),
                        _metrics(s), todo) if p]
    sources = cited(" ".join(body))
    if sources:
        body += ["References (the sources of the methods named above):", *sources]
    return body
