"""The screening rules by name: found in this package, listed for the CLI, run by name.

A new rule is a module of :mod:`analysis.screening` that defines ``RULE`` (a
:class:`~analysis.screening.rule.ScreeningRule`); nothing else needs an edit.
"""

from __future__ import annotations

import importlib
import pkgutil
from functools import cache

from ..data import RatingSet, balanced_subset
from ..errors import AnalysisError
from .result import OutlierResult
from .rule import ScreeningRule

DEFAULT_METHOD = "p913"


@cache
def rules() -> dict[str, ScreeningRule]:
    """Every rule of the package, by name, in listing order."""
    package = __name__.rsplit(".", 1)[0]
    found: list[ScreeningRule] = []
    for info in pkgutil.iter_modules(importlib.import_module(package).__path__):
        rule = getattr(importlib.import_module(f"{package}.{info.name}"), "RULE", None)
        if isinstance(rule, ScreeningRule):
            found.append(rule)
    return {r.name: r for r in sorted(found, key=lambda r: (r.order, r.name))}


def method_names() -> tuple[str, ...]:
    return tuple(rules())


def methods_help() -> str:
    """The CLI help of ``--outliers``, one phrase per rule."""
    return "rater screening: " + ", ".join(
        f"{r.name} ({'default: ' if r.name == DEFAULT_METHOD else ''}{r.summary})"
        for r in rules().values())


def check_alpha(alpha: float) -> float:
    """A significance level must be a number in (0, 0.5); anything else is refused."""
    try:
        value = float(alpha)
    except (TypeError, ValueError):
        raise AnalysisError(f"alpha {alpha!r} is not a number") from None
    if not (0.0 < value < 0.5):
        raise AnalysisError(f"alpha must lie between 0 and 0.5 (e.g. 0.05), got {alpha!r}")
    return value


def screen_raters(rs: RatingSet, method: str = DEFAULT_METHOD, *,
                  alpha: float = 0.05) -> OutlierResult:
    """Run the chosen screening; ``none`` keeps everyone.

    In an unbalanced design the rule sees the first rating of each stimulus per rater (a
    complete matrix; see :func:`~analysis.data.balanced_subset`): with every rating, raters
    would be compared on means of different precision. The result says which subset it used.
    """
    alpha = check_alpha(alpha)
    rule = rules().get(method)
    if rule is None:
        raise AnalysisError(f"unknown outlier method {method!r}; use one of "
                            f"{', '.join(method_names())}")
    if rs.n_raters < 2:  # no screening rule (``none`` included) can help here
        who = f" ({rs.raters[0]})" if rs.n_raters == 1 else ""
        raise AnalysisError(f"only {rs.n_raters} rater{who} in the ratings to analyse; DMOS, "
                            "reliability and screening need at least 2 raters: add the other "
                            "participants' session files or ratings (a pilot: 'cgvq-analyze "
                            "pilot' shows one person's ratings by level)")
    sub, text = balanced_subset(rs)
    result = rule.run(sub, alpha)
    result.subset = text
    if len(result.kept) < 2:
        raise AnalysisError(f"outlier screening ({method}) left fewer than 2 raters; use "
                            "--outliers none to inspect the data")
    return result
