"""A score anchoring: the stored monotone map from raw q onto the study's 0..100 scale.

Calibration (:mod:`cgvqm_core.calibration.anchoring`) fits the map and stores it with the
weights (key ``anchoring`` of their provenance, format ``cgvqm-anchor/1``); the metric applies
it to every result (``CGVQMResult.q_anchored``). Applying lives here, at the metric's level,
so that the metric does not depend on the calibration package above it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stimuli_manifests.formats import FormatVersionError, VersionedFormat

from .errors import CGVQMError

ANCHOR = VersionedFormat("cgvqm-anchor", 1, field="anchoring format",
                         document="score anchoring", advice="upgrade the toolkit")
ANCHOR_FORMAT = ANCHOR.version


def apply_anchor(anchor: dict[str, Any], q: np.ndarray | float) -> np.ndarray:
    """Map raw q through a stored anchoring (non-decreasing, result in [0, 100])."""
    from scipy.special import expit  # scipy on first use: `cgvqm` starts without it

    try:
        ANCHOR.check(anchor.get("format"))
    except FormatVersionError as exc:
        raise CGVQMError(str(exc)) from None
    q = np.asarray(q, dtype=np.float64)
    if anchor["kind"] == "logistic":
        lo, hi = anchor["lo"], anchor["hi"]
        out = lo + (hi - lo) * expit((q - anchor["center"]) / anchor["scale"])
    elif anchor["kind"] == "isotonic":
        out = np.interp(q, anchor["x"], anchor["y"])
    else:
        raise CGVQMError(f"unknown anchoring kind {anchor['kind']!r}")
    return np.clip(out, 0.0, 100.0)


def anchoring_for(provenance: dict[str, Any] | None, pool: str) -> dict[str, Any] | None:
    """The anchoring stored in a weights file's provenance, if it was fitted for ``pool``
    (an anchoring fitted on max-pooled q does not apply to mean-pooled q)."""
    anchor = (provenance or {}).get("anchoring")
    if not isinstance(anchor, dict) or anchor.get("pool") != pool:
        return None
    return anchor
