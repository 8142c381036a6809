"""What a screening rule returns: who was removed and why, who was kept, per-rater values."""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd


@dataclass(frozen=True)
class RemovedRater:
    """A rater taken out, with the statistic that condemned them."""

    rater: str
    method: str
    statistic: float
    critical: float
    value: float
    reason: str


@dataclass
class OutlierResult:
    """Who was removed, who was kept, and each rater's screening value."""

    method: str
    removed: list[RemovedRater]
    kept: list[int]
    deviation: dict[str, float] = field(default_factory=dict)
    # Per rater (all of them): the statistics of the rule, the decision and, for removals and
    # near-misses, why.
    table: pd.DataFrame | None = None
    notes: list[str] = field(default_factory=list)
    # The ratings the rule saw when not all of them (an unbalanced design: the first rating
    # of each stimulus per rater); empty when it saw every rating.
    subset: str = ""

    @property
    def removed_names(self) -> list[str]:
        return [r.rater for r in self.removed]
