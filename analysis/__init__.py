"""From raw ratings to DMOS, reliability, outlier raters, human ceiling and metric validation.

Library entry points (the CLI ``cgvq-analyze`` is a thin layer over these):
:func:`load_ratings` / :func:`load_sureal` read ratings into a :class:`RatingSet` (with the
sessions refused and why, in ``exclusions``), :func:`run_analysis` runs every step (the
completeness rule, screening, reliability, scores with rater-bootstrap DMOS CIs, ceiling,
data quality, metric validation), :func:`write_report` writes the report folder.
"""

from .data import Exclusion, InputProblem, RatingSet
from .errors import AnalysisError
from .inputs import load_ratings, ratings_from_frame
from .metrics import load_metric_scores, validate_metrics
from .pipeline import Analysis, AnalysisConfig, run_analysis
from .reliability import reliability
from .report import write_report
from .scores import fit_scores
from .screening import screen_raters
from .sureal_io import load_sureal, write_sureal_json
from .version import __version__

__all__ = [
    "Analysis",
    "AnalysisConfig",
    "AnalysisError",
    "Exclusion",
    "InputProblem",
    "RatingSet",
    "__version__",
    "fit_scores",
    "load_metric_scores",
    "load_ratings",
    "load_sureal",
    "ratings_from_frame",
    "reliability",
    "run_analysis",
    "screen_raters",
    "validate_metrics",
    "write_report",
    "write_sureal_json",
]
