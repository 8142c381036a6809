"""Peer metrics of CGVQM behind one registry, all reading through one streaming source.

    from cgvqm_core.metrics import MetricOptions, build_scorers, score_reference
    scorers = build_scorers(["psnr", "ssim", "flip", "cvvdp"], MetricOptions())
    per_test = score_reference("ref.mkv", ["test1.mkv", "test2.mkv"], scorers)

``entries()`` lists every registered metric with its spec and availability here;
``metric_table_rows()`` the same as plain data (``cgvqm metrics``, the docs' metric table).
"""

from .engine import score_reference
from .registry import (
    HIGHER,
    LOWER,
    Availability,
    Entry,
    MetricOptions,
    MetricScore,
    MetricSpec,
    build_scorers,
    entries,
    get_entry,
    metric_table_rows,
    parse_metric_list,
    readers,
)
from .viewing import ViewingCondition

__all__ = ["HIGHER", "LOWER", "Availability", "Entry", "MetricOptions", "MetricScore",
           "MetricSpec", "ViewingCondition", "build_scorers", "entries", "get_entry",
           "metric_table_rows", "parse_metric_list", "readers", "score_reference"]
