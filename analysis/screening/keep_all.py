"""``none``: keep every rater (to inspect the data before any screening)."""

from __future__ import annotations

import pandas as pd

from ..data import RatingSet
from .result import OutlierResult
from .rule import ScreeningRule


def keep_everyone(rs: RatingSet) -> OutlierResult:
    """No screening: every rater is kept."""
    return OutlierResult("none", [], list(range(rs.n_raters)),
                         table=pd.DataFrame({"decision": "kept", "reason": ""},
                                            index=pd.Index(rs.raters, name="rater")))


RULE = ScreeningRule(name="none", order=3, summary="no screening", screen=keep_everyone)
