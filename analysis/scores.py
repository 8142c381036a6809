"""Quality scores per stimulus, rater and content, and DMOS per ITU-T P.910.

Models (``--model``):

- ``mle``: SUREAL's MaximumLikelihoodEstimationModel (Li & Bampis 2020): quality, rater
  bias and inconsistency, content ambiguity, each with a 95% CI;
- ``p910``: SUREAL's MLE_CO_AP2, the ITU-T P.910 subject model (no content ambiguity);
- ``mos``: plain means with Student-t CIs;
- ``bt500``: SUREAL's ITU-R BT.500 rater rejection, then plain means.

Repetitions enter as repeated votes. SUREAL prints progress on stdout; it is silenced here.
DMOS(v) = Q(v) - Q(ref(v)) + ref_score, where the hidden reference's score gives Q(ref); its
95% CI comes from a bootstrap over raters (:mod:`analysis.intervals`), which keeps the
covariance of Q(v) and Q(ref) that adding their CIs in quadrature would ignore. A hidden
reference's DMOS is ref_score by definition (CI of zero width).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .data import InputProblem, RatingSet
from .errors import AnalysisError
from .intervals import (
    dmos_from_quality_matrix,
    estimator_weights,
    rater_bootstrap,
    reported_halfwidth,
)
from .subject_models import (
    bt500_rejection,
    implausible,
    mos_and_t,
    plausible,
    rater_stats_from_means,
    run_sureal,
)

log = logging.getLogger(__name__)

MODELS = ("mle", "p910", "mos", "bt500")
MODEL_NAMES = {
    "mle": "SUREAL MLE (MaximumLikelihoodEstimationModel)",
    "p910": "SUREAL MLE_CO_AP2 (ITU-T P.910 subject model)",
    "mos": "MOS (plain means, t-based CI)",
    "bt500": "BT.500 rater rejection + MOS (SUREAL SR_MOS)",
}


@dataclass
class ScoreResult:
    """Per-stimulus quality and DMOS with 95% CIs, plus the subject/content parameters."""

    model: str
    quality: np.ndarray
    quality_halfwidth: np.ndarray
    mos: np.ndarray
    n_ratings: np.ndarray
    dmos: np.ndarray
    dmos_halfwidth: np.ndarray
    raters: list[str]
    rater_bias: np.ndarray | None = None
    rater_bias_ci: np.ndarray | None = None  # (S, 2) low/high
    rater_inconsistency: np.ndarray | None = None
    rater_inconsistency_ci: np.ndarray | None = None
    content: list[str] = field(default_factory=list)
    content_ambiguity: np.ndarray | None = None
    content_ambiguity_ci: np.ndarray | None = None
    rejected: list[str] = field(default_factory=list)
    problems: list[InputProblem] = field(default_factory=list)
    fallback: str | None = None  # why the requested model was replaced, when it was
    bootstrap: object | None = None  # analysis.intervals.RaterBootstrap behind the DMOS CIs

    @property
    def model_name(self) -> str:
        return MODEL_NAMES.get(self.model, self.model)


def _ci_pair(ci95: list, value: np.ndarray) -> np.ndarray:
    """SUREAL gives CI as [lower distances, upper distances]; turn into absolute bounds."""
    lo = np.asarray(ci95[0], dtype=float)
    hi = np.asarray(ci95[1], dtype=float)
    return np.c_[value - lo, value + hi]


def _no_ci_at_zero(value: np.ndarray, ci: np.ndarray) -> np.ndarray:
    """``ci`` with no interval where the estimate sits at its boundary 0: SUREAL's full MLE
    identifies only inconsistency^2 + ambiguity^2 per rating, its optimiser often leaves the
    least noisy rater (or content) at 0 on that flat ridge, and the curvature there gives a
    "CI" like [1e-46, 2e-46], which is no interval."""
    at_zero = value <= 1e-6 * max(float(np.nanmax(value, initial=0.0)), 1.0)
    out = ci.copy()
    out[at_zero] = np.nan
    return out


def check_not_constant(rs: RatingSet) -> None:
    """Refuse a panel whose ratings are all equal: no score model can say anything."""
    votes = rs.scores[np.isfinite(rs.scores)]
    if votes.size and np.ptp(votes) == 0:
        raise AnalysisError(f"all {votes.size} ratings are equal ({votes[0]:g}): there is no "
                            "variation to analyse; check the input")


def fit_scores(rs: RatingSet, model: str = "mle", *, n_boot: int = 1000,
               seed: int = 0) -> ScoreResult:
    """Quality scores of every stimulus under the chosen model, DMOS from them, and DMOS CIs
    from ``n_boot`` resamples of the raters (seeded)."""
    if model not in MODELS:
        raise AnalysisError(f"unknown score model {model!r}; use one of {', '.join(MODELS)}")
    if rs.n_raters < 2:
        raise AnalysisError("at least 2 raters are needed to fit a score model")
    check_not_constant(rs)
    rejected: list[str] = []
    work = rs
    if model == "bt500":
        flags, _, _ = bt500_rejection(rs)
        rejected = [r for r, f in zip(rs.raters, flags, strict=True) if f]
        work = rs.with_raters([s for s, f in enumerate(flags) if not f])
        if work.n_raters < 2:
            raise AnalysisError(f"BT.500 rejected {len(rejected)} of {rs.n_raters} raters, "
                                "leaving fewer than 2; use --model mos")
    mos, mos_half, n = mos_and_t(work.scores)
    result = ScoreResult(
        model=model, quality=mos, quality_halfwidth=mos_half, mos=mos, n_ratings=n,
        dmos=mos, dmos_halfwidth=mos_half, raters=list(work.raters), rejected=rejected,
    )
    if model in ("mos", "bt500"):
        b, bci, v, vci = rater_stats_from_means(work, mos)
        result.rater_bias, result.rater_bias_ci = b, bci
        result.rater_inconsistency, result.rater_inconsistency_ci = v, vci
        result.problems += unrated_after_rejection(rs, work, rejected)
    else:
        from sureal.subjective_model import (
            MaximumLikelihoodEstimationModel,
            MaximumLikelihoodEstimationModelContentObliviousAlternativeProjection2,
        )

        cls = (MaximumLikelihoodEstimationModel if model == "mle"
               else MaximumLikelihoodEstimationModelContentObliviousAlternativeProjection2)
        out = run_sureal(cls, work)
        why = unusable(out, work)
        if model == "mle" and why is not None:
            # SUREAL's full MLE can diverge (content ambiguity -> inf) when one rater is far
            # noisier than the rest; the P.910 model is the stable fallback.
            msg = (f"SUREAL MLE did not converge to plausible values ({why}); fell back to "
                   "MLE_CO_AP2 (p910)")
            log.warning(msg)
            result.problems.append(InputProblem("score model", None, msg))
            result.fallback = msg
            result.model = model = "p910"
            out = run_sureal(
                MaximumLikelihoodEstimationModelContentObliviousAlternativeProjection2, work)
            why = unusable(out, work)
        if why is not None:
            raise sureal_failure(model, why, fell_back=result.fallback is not None)
        q = np.asarray(out["quality_scores"], dtype=float)
        result.quality = q
        result.quality_halfwidth = np.asarray(out["quality_scores_ci95"][1], dtype=float)
        bias = np.asarray(out["observer_bias"], dtype=float)
        result.rater_bias = bias
        result.rater_bias_ci = _ci_pair(out["observer_bias_ci95"], bias)
        inc = np.asarray(out["observer_inconsistency"], dtype=float)
        result.rater_inconsistency = inc
        result.rater_inconsistency_ci = _no_ci_at_zero(
            inc, _ci_pair(out["observer_inconsistency_ci95"], inc))
        if "content_ambiguity" in out:
            amb = np.asarray(out["content_ambiguity"], dtype=float)
            result.content = list(dict.fromkeys(work.stimuli["reference"]))
            result.content_ambiguity = amb
            result.content_ambiguity_ci = _no_ci_at_zero(
                amb, _ci_pair(out["content_ambiguity_ci95"], amb))
    result.dmos, _, dmos_problems = dmos_from_quality(rs, result.quality,
                                                      result.quality_halfwidth)
    result.problems += dmos_problems
    boot = rater_bootstrap(work, estimator_weights(work, result), n_boot, seed)
    half = boot.halfwidth()  # bt500: over the raters its screening kept, like the DMOS
    result.dmos_halfwidth = np.where(rs.hidden_reference_mask, 0.0, half)
    result.bootstrap = boot
    return result


def unusable(out: dict, rs: RatingSet) -> str | None:
    """Why the SUREAL result ``out`` cannot be used (None: it can), for every model."""
    if plausible(out, rs):
        return None
    return implausible(out, rs) or "values outside the plausible range"


def sureal_failure(model: str, why: str, *, fell_back: bool) -> AnalysisError:
    """The error for a SUREAL model whose result cannot be used: SUREAL's own words and what
    to try (plain means need no convergence)."""
    which = "SUREAL MLE and its fallback MLE_CO_AP2 (p910)" if fell_back else \
        MODEL_NAMES.get(model, model)
    return AnalysisError(
        f"{which} gave no usable scores on these ratings ({why}); try --model mos, and check "
        "for stimuli or raters with very few ratings (tables/problems.csv)")


def unrated_after_rejection(rs: RatingSet, work: RatingSet,
                            rejected: list[str]) -> list[InputProblem]:
    """BT.500's rejection removes raters inside the model: the stimuli only they rated get no
    score (NaN DMOS, left out of the metric statistics); name them rather than stay silent."""
    lost = [s for s, r in zip(rs.stimulus_ids, np.isfinite(work.scores).any(axis=(1, 2)),
                              strict=True) if not r]
    if not lost:
        return []
    return [InputProblem("score model", None, (
        f"{len(lost)} stimul{'us' if len(lost) == 1 else 'i'} rated only by the raters BT.500 "
        f"rejected ({', '.join(rejected)}) have no score (DMOS NaN, left out of the metric "
        f"statistics): {', '.join(lost)}"))]


def dmos_from_quality(
    rs: RatingSet, quality: np.ndarray, halfwidth: np.ndarray
) -> tuple[np.ndarray, np.ndarray, list[InputProblem]]:
    """DMOS = Q(v) - Q(ref(v)) + ref_score (:func:`~analysis.intervals.dmos_from_quality_matrix`;
    and, for reference only, the half-widths in quadrature, which ignores their covariance;
    the reported CIs come from :mod:`analysis.intervals`). A hidden reference gets ref_score.
    Stimuli whose reference was never rated as hidden reference have no DMOS, unless none
    was rated (reported as a problem either way).
    """
    ref = rs.reference_index()
    has = ref >= 0
    dmos = dmos_from_quality_matrix(rs, quality[:, None])[:, 0]
    half = halfwidth.astype(float).copy()
    hidden = rs.hidden_reference_mask
    cond = has & ~hidden
    half[cond] = np.sqrt(halfwidth[cond] ** 2 + halfwidth[ref[cond]] ** 2)
    half[~has] = np.where(has.any(), np.nan, half[~has])
    problems = []
    if (~has).any():
        missing = sorted(set(rs.stimuli["reference"].to_numpy()[~has]))
        what = (f"{', '.join(map(str, missing[:5]))}{' ...' if len(missing) > 5 else ''}: "
                "their stimuli have no DMOS (their quality score and MOS are in the table; "
                "they are left out of the metric statistics)" if has.any() else
                "any stimulus: the dmos column holds quality scores (no difference to a "
                "reference could be taken)")
        problems.append(InputProblem(rs.source or "<ratings>", None,
                                     f"no hidden-reference ratings for {what}"))
    return dmos, half, problems


def dmos_table(rs: RatingSet, res: ScoreResult) -> pd.DataFrame:
    """The DMOS table (cgvq-dmos/1, docs/file-formats.md): its columns first, then scene,
    quality and its CI."""
    st = rs.stimuli
    half = res.dmos_halfwidth
    if res.bootstrap is not None:  # too few raters: no interval (see MIN_RATERS_FOR_INTERVAL)
        half = reported_halfwidth(res.bootstrap, half, rs.hidden_reference_mask)
    return pd.DataFrame({
        "stimulus": st.index.astype(str),
        "reference": st["reference"].to_numpy(),
        "method": st["method"].to_numpy(),
        "level": pd.array(st["level"], dtype="Int64"),
        "dmos": res.dmos,
        "ci95_low": res.dmos - half,
        "ci95_high": res.dmos + half,
        "mos": res.mos,
        "n_ratings": res.n_ratings.astype(int),
        "model": res.model_name,
        "scene": st["scene"].to_numpy(),
        "quality": res.quality,
        "quality_ci95_low": res.quality - res.quality_halfwidth,
        "quality_ci95_high": res.quality + res.quality_halfwidth,
        "is_hidden_reference": st["is_hidden_reference"].to_numpy(),
    })
