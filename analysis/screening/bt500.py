"""``bt500``: ITU-R BT.500 kurtosis-based rater screening, as SUREAL implements it."""

from __future__ import annotations

import pandas as pd

from ..data import RatingSet
from ..subject_models import bt500_rejection
from .result import OutlierResult, RemovedRater
from .rule import ScreeningRule


def bt500_screen(rs: RatingSet) -> OutlierResult:
    """ITU-R BT.500 kurtosis screening: reject when (P+Q)/N > 0.05 and |P-Q|/(P+Q) < 0.3."""
    rejected, first, second = bt500_rejection(rs)
    removed = [
        RemovedRater(
            rater=rs.raters[s], method="bt500", statistic_name="outside_share",
            statistic=first[s], critical=0.05, second_name="one_sidedness", second=second[s],
            second_critical=0.3,
            reason=(f"{first[s]:.1%} of the votes lie outside the BT.500 bounds (> 5%) and "
                    f"they are not one-sided (|P-Q|/(P+Q) = {second[s]:.2f} < 0.3)"),
        )
        for s in range(rs.n_raters) if rejected[s]
    ]
    kept = [s for s in range(rs.n_raters) if not rejected[s]]
    table = pd.DataFrame({"outside_share": first, "one_sidedness": second,
                          "decision": ["removed" if r else "kept" for r in rejected],
                          "reason": [next((x.reason for x in removed if x.rater == name), "")
                                     for name in rs.raters]},
                         index=pd.Index(rs.raters, name="rater"))
    return OutlierResult("bt500", removed, kept, {r: f for r, f in zip(rs.raters, first,
                                                                      strict=True)},
                         table=table)


RULE = ScreeningRule(name="bt500", order=2, summary="ITU-R BT.500 kurtosis screening",
                     screen=bt500_screen)
