"""The shape of a screening rule: a name for ``--outliers``, a line of help, the function."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ..data import RatingSet
from .result import OutlierResult


@dataclass(frozen=True)
class ScreeningRule:
    """One rule. A module of this package that defines ``RULE`` is registered by its name."""

    name: str
    order: int
    """Position in listings and in the CLI help (the default rule first)."""
    summary: str
    screen: Callable[..., OutlierResult]
    """``screen(rs)``, or ``screen(rs, alpha)`` when ``uses_alpha``."""
    uses_alpha: bool = False
    min_raters: int = 2
    """Below this many raters the rule cannot test anyone (and removes no one)."""

    def run(self, rs: RatingSet, alpha: float) -> OutlierResult:
        return self.screen(rs, alpha) if self.uses_alpha else self.screen(rs)
