"""Calibrating CGVQM: fitting the channel weights (omega) and scale (alpha) to human scores.

Pipeline: :mod:`.data` (manifest + DMOS CSV -> videos and targets), :mod:`.cache` (per-patch
channel features, computed once, resumable), :mod:`.fitting` (the upstream objective,
vectorised), :mod:`.splits` and :mod:`.validation` (scene-disjoint repeated splits),
:mod:`.anchoring` (fitting the monotone map onto the 0..100 scale), :mod:`.pipeline` (all of
it, to a weights file), :mod:`.ray_features` (the features on a Ray cluster) and :mod:`.cli`
(``cgvqm calibrate``).

Names are imported on first use, so that ``cgvqm`` can register its ``calibrate``
subcommand without loading pandas and scipy for the other subcommands.
"""

from __future__ import annotations

import importlib
from typing import Any

# name -> the module that defines it, relative to this package (applying an anchoring is the
# metric's own, one level up)
_WHERE = {
    "anchoring_for": ".scale_anchor", "apply_anchor": ".scale_anchor",
    "fit_anchor": "anchoring", "refit_alpha": "anchoring",
    "DatasetSpec": "arguments",
    "FeatureCache": "cache", "pack": "cache",
    "load_dataset": "data", "load_datasets": "data", "read_dmos_csv": "data",
    "FitConfig": "fitting", "FitResult": "fitting", "fit": "fitting",
    "pooled_errors": "fitting",
    "Split": "splits", "repeated_splits": "splits", "scene_split": "splits",
    "CalibrationData": "validation", "ValidationResult": "validation", "validate": "validation",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
