"""What a screening rule returns: who was removed and why, who was kept, per-rater values."""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd


@dataclass(frozen=True)
class RemovedRater:
    """A rater taken out, with the statistics that condemned them, each named with its
    critical value: every rule here has a main test and a second one that must agree or that
    describes the outlier (P.913: r1, then the inconsistency's robust z; BT.500: the share
    of votes outside the bounds, then their one-sidedness; Grubbs: G, then the deviation
    it was computed from, which has no threshold of its own)."""

    rater: str
    method: str
    statistic_name: str
    statistic: float
    critical: float
    second_name: str
    second: float
    second_critical: float
    reason: str

    COLUMNS = ("rater", "method", "statistic_name", "statistic", "critical", "second_name",
               "second", "second_critical", "reason")
    """The order of the report's ``tables/outliers.csv``."""


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
