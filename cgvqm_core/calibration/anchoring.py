"""Putting calibrated scores on the study's 0..100 scale.

The PLCC objective leaves the scale free: any positive multiple of omega or alpha fits as
well. After the fit, two steps (both on training videos only) make a score of 75 mean what
the rating scale's label at 75 means ("Perceptible but not annoying"):

1. ``alpha`` is refitted by least squares so that q = 100 - alpha * e matches the human
   scores with the metric's fixed point kept (no error = 100 = imperceptible);
2. a monotone non-decreasing map from raw q to the human scale, either a four-parameter
   logistic (smooth, strictly increasing, default) or an isotonic regression interpolated
   between its steps. Both are clipped to [0, 100].

The map is stored with the weights (key ``anchoring`` of the provenance, format
``cgvqm-anchor/1``) and applied to q computed with the same pooling by the metric itself
(:func:`cgvqm_core.scale_anchor.apply_anchor`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import isotonic_regression, least_squares
from scipy.special import expit

from ..errors import CGVQMError
from ..scale_anchor import ANCHOR_FORMAT
from .arguments import ANCHOR_METHODS as METHODS


def refit_alpha(pooled_error: np.ndarray, target: np.ndarray) -> float:
    """The alpha >= 0 minimising sum (100 - alpha * e - y)^2 (closed form)."""
    e = np.asarray(pooled_error, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64)
    den = float(e @ e)
    if den <= 0:
        raise CGVQMError("all training videos have zero feature error: nothing to calibrate "
                         "(are the test videos identical to their references?)")
    return max(float(e @ (100.0 - y)) / den, 0.0)


def _logistic(params: np.ndarray, q: np.ndarray) -> np.ndarray:
    lo, u, center, log_scale = params
    hi = lo + (100.0 - lo) * u
    return lo + (hi - lo) * expit((q - center) / np.exp(log_scale))


def fit_anchor(q: np.ndarray, target: np.ndarray, method: str = "logistic", *,
               pool: str = "max") -> dict[str, Any]:
    """Fit a non-decreasing map from raw q to the 0..100 target; returns its description."""
    q = np.asarray(q, dtype=np.float64)
    y = np.clip(np.asarray(target, dtype=np.float64), 0.0, 100.0)
    if q.size < 3:
        raise CGVQMError(f"the scale anchoring needs at least 3 training videos, got {q.size}")
    base = {"format": ANCHOR_FORMAT, "pool": pool, "input": "q (raw CGVQM score)",
            "output": "0..100 quality scale of the study (100 = imperceptible)",
            "domain": [float(q.min()), float(q.max())], "n_videos": int(q.size)}
    if method == "logistic":
        spread = float(np.std(q)) or 1.0
        lo0, hi0 = float(y.min()), float(y.max())
        u0 = (hi0 - lo0) / max(100.0 - lo0, 1e-6)
        x0 = np.array([min(lo0, 99.0), np.clip(u0, 0.01, 1.0), float(np.median(q)),
                       np.log(spread / 2)])
        res = least_squares(lambda p: _logistic(p, q) - y, x0,
                            bounds=([0.0, 0.0, -np.inf, np.log(spread) - 12],
                                    [100.0, 1.0, np.inf, np.log(spread) + 12]))
        lo, u, center, log_scale = (float(v) for v in res.x)
        return {**base, "kind": "logistic", "lo": lo, "hi": lo + (100.0 - lo) * u,
                "center": center, "scale": float(np.exp(log_scale))}
    if method == "isotonic":
        order = np.argsort(q, kind="stable")
        fitted = isotonic_regression(y[order], increasing=True)
        xs, ys = [], []
        for start, stop in zip(fitted.blocks[:-1], fitted.blocks[1:], strict=True):
            xs.append(float(q[order][start:stop].mean()))
            ys.append(float(fitted.x[start]))
        return {**base, "kind": "isotonic", "x": xs, "y": ys}
    raise CGVQMError(f"unknown anchoring method {method!r}; choose {' or '.join(METHODS)}")
