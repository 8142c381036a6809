"""From raw ratings to DMOS, reliability, outlier raters, human ceiling and metric validation.

Library entry points (the CLI ``cgvq-analyze`` is a thin layer over these):
:func:`load_ratings` / :func:`load_sureal` read ratings into a :class:`RatingSet` (with the
sessions refused and why, in ``exclusions``), :func:`run_analysis` runs every step (the
completeness rule, screening, reliability, scores with rater-bootstrap DMOS CIs, ceiling,
data quality, metric validation), :func:`write_report` writes the report folder.

The names are imported when first used: a reader of one small module (the study server's
flag thresholds, say) does not pay for the whole statistics stack (pandas, SciPy, pingouin,
matplotlib: seconds on a small machine). ``analysis.reliability`` is the module (its
function: ``from analysis.reliability import reliability``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .version import __version__

#: public name -> the module that defines it
_EXPORTS = {
    "Exclusion": ".data", "InputProblem": ".data", "RatingSet": ".data",
    "AnalysisError": ".errors",
    "load_ratings": ".inputs", "ratings_from_frame": ".inputs",
    "load_metric_scores": ".metric_scores", "validate_metrics": ".metrics",
    "Analysis": ".pipeline", "AnalysisConfig": ".pipeline", "run_analysis": ".pipeline",
    "write_report": ".report",
    "fit_scores": ".scores",
    "screen_raters": ".screening",
    "load_sureal": ".sureal_io", "write_sureal_json": ".sureal_io",
}

if TYPE_CHECKING:
    from .data import Exclusion, InputProblem, RatingSet
    from .errors import AnalysisError
    from .inputs import load_ratings, ratings_from_frame
    from .metric_scores import load_metric_scores
    from .metrics import validate_metrics
    from .pipeline import Analysis, AnalysisConfig, run_analysis
    from .report import write_report
    from .scores import fit_scores
    from .screening import screen_raters
    from .sureal_io import load_sureal, write_sureal_json


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'analysis' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # once: later lookups do not come here
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


__all__ = [  # the names of _EXPORTS (a test holds them equal), and the version
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
    "run_analysis",
    "screen_raters",
    "validate_metrics",
    "write_report",
    "write_sureal_json",
]
