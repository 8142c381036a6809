"""The whole analysis of one study, step by step, as one result object."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from .ceiling import CiCurve, SplitHalf, ci_width_curve, split_half
from .data import Exclusion, InputProblem, RatingSet, drop_unrated, rater_order
from .errors import AnalysisError, check_resamples
from .intervals import MIN_RATERS_FOR_INTERVAL
from .metrics import MetricScores, MetricValidation, validate_metrics
from .panel import (
    PanelSummary,
    drop_failed_vision,
    panel_problems,
    summarise_panel,
    vision_column,
)
from .quality import altered_at, drop_incomplete, quality_table
from .reliability import Reliability, reliability
from .scores import ScoreResult, check_not_constant, dmos_table, fit_scores
from .screening import DEFAULT_METHOD, OutlierResult, check_alpha, screen_raters

log = logging.getLogger(__name__)

DEFAULT_MIN_COMPLETENESS = 0.5


@dataclass
class AnalysisConfig:
    """Choices of a run (CLI flags map one to one)."""

    model: str = "mle"
    outliers: str = DEFAULT_METHOD
    alpha: float = 0.05
    seed: int = 0
    n_boot: int = 1000
    n_splits: int = 1000
    ci_draws: int = 100
    min_completeness: float = DEFAULT_MIN_COMPLETENESS
    exclude_failed_vision: bool = False

    def check(self) -> AnalysisConfig:
        """Refuse values that would give silently wrong numbers (one clear message each)."""
        self.alpha = check_alpha(self.alpha)
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or \
                self.seed < 0:
            raise AnalysisError(f"seed must be a whole number >= 0, got {self.seed!r}")
        for name in ("n_boot", "n_splits", "ci_draws"):
            setattr(self, name, check_resamples(getattr(self, name), name))
        c = self.min_completeness
        if not isinstance(c, (int, float)) or not math.isfinite(c) or not 0 <= c <= 1:
            raise AnalysisError(f"min-completeness must lie in [0, 1] (e.g. 0.5), got {c!r}")
        return self


@dataclass
class Analysis:
    """Every result of :func:`run_analysis` (inputs kept for figures and exports)."""

    config: AnalysisConfig
    ratings: RatingSet  # as read
    screened: RatingSet  # after the completeness rule and outlier removal
    outliers: OutlierResult
    reliability: Reliability | None
    scores: ScoreResult
    ceiling: SplitHalf | None
    ci_curve: CiCurve | None
    metrics: MetricValidation | None
    timings: dict[str, float] = field(default_factory=dict)
    problems: list[InputProblem] = field(default_factory=list)
    exclusions: list[Exclusion] = field(default_factory=list)
    quality: pd.DataFrame | None = None  # per rater data quality (analysis.quality)
    used: RatingSet | None = None  # after the completeness rule, before screening
    panel: PanelSummary | None = None  # who took part, from the questionnaires

    def dmos(self) -> pd.DataFrame:
        return dmos_table(self.screened, self.scores)

    @property
    def partial_kept(self) -> list[tuple[str, float]]:
        """Raters kept although their sessions are incomplete: (rater, completeness); a
        session file altered outside the app is not an incomplete session
        (:attr:`altered_kept`)."""
        rs = self.used or self.screened
        comp = rs.completeness()
        return [(r, float(c)) for r, c in zip(rs.raters, comp, strict=True)
                if np.isfinite(c) and c < 1.0 - 1e-9 and not altered_at(rs, r)]

    @property
    def altered_kept(self) -> list[tuple[str, str]]:
        """Raters kept whose session file was altered outside the app, with the authentic
        ratings before the change: (rater, where the file fails its check)."""
        rs = self.used or self.screened
        return [(r, where) for r in rs.raters if (where := altered_at(rs, r))]


def prepare(rs: RatingSet, config: AnalysisConfig) -> tuple[RatingSet, OutlierResult,
                                                            RatingSet]:
    """The vision and completeness rules and the rater screening: (used, screening result,
    screened)."""
    if config.exclude_failed_vision:
        rs = drop_failed_vision(rs)
    used = drop_incomplete(rs, config.min_completeness)
    check_not_constant(used)
    outliers = screen_raters(used, config.outliers, alpha=config.alpha)
    screened = drop_unrated(used.with_raters(outliers.kept), "screening",
                            f"their raters were screened out by --outliers {outliers.method}")
    exclusions = list(used.exclusions) + [
        Exclusion("screened out", r.rater, r.reason, f"--outliers {outliers.method}")
        for r in outliers.removed]
    return used, outliers, replace(screened, exclusions=exclusions)


MODEL_REJECTION = "rejected by the score model"


def without_model_rejected(screened: RatingSet, scores: ScoreResult) -> RatingSet:
    """The raters a score model rejected itself (``--model bt500``) left out of everything
    after it (reliability, ceiling, counts), as an exclusion of their own: the scores use
    only the others, so every number beside them must too. The stimuli keep their rows (the
    scores are per stimulus of ``screened``); one only they rated has a NaN score."""
    if not scores.rejected:
        return screened
    gone = set(scores.rejected)
    kept = screened.with_raters([i for i, r in enumerate(screened.raters) if r not in gone])
    kept.exclusions += [Exclusion(MODEL_REJECTION, r, "ITU-R BT.500 rater rejection "
                                  "(kurtosis-based, SUREAL) in the score model",
                                  f"--model {scores.model}") for r in scores.rejected]
    return kept


def _quality(rs: RatingSet, used: RatingSet, outliers: OutlierResult, scores: ScoreResult,
             config: AnalysisConfig) -> pd.DataFrame:
    """The data-quality table of everyone read, with who the rules removed and why."""
    info = used.rater_info if used.rater_info is not None else rs.rater_info
    quality = quality_table(replace(rs, rater_info=info), screening=outliers.table,
                            min_completeness=config.min_completeness)
    for r in outliers.removed:
        quality.loc[r.rater, "status"] = f"removed ({outliers.method})"
    for rater in scores.rejected:
        quality.loc[rater, "status"] = f"removed (--model {config.model})"
    if rs.panel is not None and rs.panel.screenings:
        quality["vision"] = vision_column(rs, list(quality.index))
        for rater in rs.panel.failed_vision():
            if config.exclude_failed_vision and rater in quality.index:
                quality.loc[rater, "status"] = "excluded (vision check)"
    return quality


def run_analysis(rs: RatingSet, config: AnalysisConfig | None = None,
                 metric_scores: MetricScores | None = None, *, progress: bool = True) -> Analysis:
    """Completeness rule, screening, reliability, scores and DMOS, ceiling, metric validation."""
    config = (config or AnalysisConfig()).check()
    timings: dict[str, float] = {}
    steps = ["outliers", "reliability", "scores", "ceiling", "ci curve", "quality"] + (
        ["metrics"] if metric_scores is not None else [])
    bar = tqdm(total=len(steps), desc="analysis", disable=not progress, leave=False)

    def step(name: str) -> None:
        timings[name] = time.perf_counter()
        bar.set_postfix_str(name)

    def done(name: str) -> None:
        timings[name] = time.perf_counter() - timings[name]
        bar.update(1)

    step("outliers")
    used, outliers, screened = prepare(rs, config)
    problems = list(screened.problems)  # used's, plus the stimuli the screening emptied
    exclusions = list(screened.exclusions)
    done("outliers")
    step("scores")
    scores = fit_scores(screened, config.model, n_boot=config.n_boot, seed=config.seed)
    problems += scores.problems
    screened = without_model_rejected(screened, scores)
    exclusions = list(screened.exclusions)
    done("scores")
    step("reliability")
    try:
        rel = reliability(screened, n_boot=min(200, config.n_boot), seed=config.seed)
    except AnalysisError as exc:
        problems.append(InputProblem("reliability", None, str(exc)))
        rel = None
    done("reliability")
    step("ceiling")
    try:
        ceiling = split_half(screened, config.n_splits, config.seed)
    except AnalysisError as exc:
        problems.append(InputProblem("ceiling", None, str(exc)))
        ceiling = None
    done("ceiling")
    step("ci curve")
    curve = ci_width_curve(screened, config.ci_draws, config.seed) \
        if screened.n_raters > MIN_RATERS_FOR_INTERVAL else None  # a curve: 2 panel sizes
    done("ci curve")
    step("quality")
    quality = _quality(rs, used, outliers, scores, config)
    panel = None
    if rs.panel is not None and rs.panel.definition is not None:
        problems += panel_problems(rs.panel)
        # everyone read, and those a vision check stopped before their first rating
        everyone = list(rs.raters) + rater_order(set(rs.panel.screenings) - set(rs.raters))
        panel = summarise_panel(rs.panel.definition, rs.panel, list(screened.raters),
                                everyone)
    done("quality")
    validation = None
    if metric_scores is not None:
        step("metrics")
        validation = validate_metrics(
            dmos_table(screened, scores), metric_scores, boot=scores.bootstrap,
            n_boot=config.n_boot, seed=config.seed, alpha=config.alpha,
            ceiling=ceiling.summary() if ceiling is not None else None)
        problems += [p for p in validation.problems if p not in problems]
        done("metrics")
    bar.close()
    return Analysis(config, rs, screened, outliers, rel, scores, ceiling, curve, validation,
                    timings, problems, exclusions, quality, used, panel)
