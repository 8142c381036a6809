"""The whole analysis of one study, step by step, as one result object."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from tqdm.auto import tqdm

from .ceiling import CiCurve, SplitHalf, ci_width_curve, split_half
from .data import InputProblem, RatingSet
from .errors import AnalysisError
from .metrics import MetricScores, MetricValidation, validate_metrics
from .outliers import OutlierResult, screen_raters
from .reliability import Reliability, reliability
from .scores import ScoreResult, dmos_table, fit_scores

log = logging.getLogger(__name__)


@dataclass
class AnalysisConfig:
    """Choices of a run (CLI flags map one to one)."""

    model: str = "mle"
    outliers: str = "grubbs"
    alpha: float = 0.05
    seed: int = 0
    n_boot: int = 1000
    n_splits: int = 1000
    ci_draws: int = 100


@dataclass
class Analysis:
    """Every result of :func:`run_analysis` (inputs kept for figures and exports)."""

    config: AnalysisConfig
    ratings: RatingSet  # as read
    screened: RatingSet  # after outlier removal
    outliers: OutlierResult
    reliability: Reliability | None
    scores: ScoreResult
    ceiling: SplitHalf | None
    ci_curve: CiCurve | None
    metrics: MetricValidation | None
    timings: dict[str, float] = field(default_factory=dict)
    problems: list[InputProblem] = field(default_factory=list)

    def dmos(self):
        return dmos_table(self.screened, self.scores)


def run_analysis(rs: RatingSet, config: AnalysisConfig | None = None,
                 metric_scores: MetricScores | None = None, *, progress: bool = True) -> Analysis:
    """Screen raters, then reliability, scores and DMOS, ceiling, metric validation."""
    config = config or AnalysisConfig()
    timings: dict[str, float] = {}
    problems = list(rs.problems)
    steps = ["outliers", "reliability", "scores", "ceiling", "ci curve"] + (
        ["metrics"] if metric_scores is not None else [])
    bar = tqdm(total=len(steps), desc="analysis", disable=not progress, leave=False)

    def step(name: str) -> None:
        timings[name] = time.perf_counter()
        bar.set_postfix_str(name)

    def done(name: str) -> None:
        timings[name] = time.perf_counter() - timings[name]
        bar.update(1)

    step("outliers")
    outliers = screen_raters(rs, config.outliers, alpha=config.alpha)
    screened = rs.with_raters(outliers.kept)
    done("outliers")
    step("reliability")
    try:
        rel = reliability(screened)
    except AnalysisError as exc:
        problems.append(InputProblem("reliability", None, str(exc)))
        rel = None
    done("reliability")
    step("scores")
    scores = fit_scores(screened, config.model)
    problems += scores.problems
    done("scores")
    step("ceiling")
    try:
        ceiling = split_half(screened, config.n_splits, config.seed)
    except AnalysisError as exc:
        problems.append(InputProblem("ceiling", None, str(exc)))
        ceiling = None
    done("ceiling")
    step("ci curve")
    curve = ci_width_curve(screened, config.ci_draws, config.seed) \
        if screened.n_raters >= 3 else None
    done("ci curve")
    validation = None
    if metric_scores is not None:
        step("metrics")
        validation = validate_metrics(
            dmos_table(screened, scores), metric_scores, n_boot=config.n_boot,
            seed=config.seed, alpha=config.alpha,
            ceiling=ceiling.summary() if ceiling is not None else None)
        problems += [p for p in validation.problems if p not in problems]
        done("metrics")
    bar.close()
    return Analysis(config, rs, screened, outliers, rel, scores, ceiling, curve, validation,
                    timings, problems)
