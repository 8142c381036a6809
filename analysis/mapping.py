"""The monotone mapping from a metric's score to DMOS, fitted once or inside every resample.

The 5-parameter logistic of VQEG / Sheikh et al. (2006),
``q' = b1 (0.5 - 1 / (1 + exp(b2 (q - b3)))) + b4 q + b5``, is fitted on standardised scores
from several starts, within bounds that keep it monotone in the direction of the data's
trend (``b2 > 0``, ``b1`` and ``b4`` of the trend's sign); when no fit succeeds, or fewer
than :data:`MIN_LOGISTIC_STIMULI` stimuli are there to fit its five parameters, a straight
line is used and the table says so.

Bootstrap intervals must refit the mapping in every resample (a mapping fitted once on all
data makes the intervals too narrow). :func:`refit_batch` does that for all resamples at once:
a Levenberg-Marquardt iteration on ``(B, n)`` arrays, started from the full-data fit, with the
same bounds and the same monotone-or-line rule per resample.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

log = logging.getLogger(__name__)

N_PARAMS = {"logistic5": 5, "linear (fallback)": 2}
MAPPING_FUNCTIONS = {
    "logistic5": "dmos = b1 (1/2 - 1 / (1 + exp(b2 (z - b3)))) + b4 z + b5, "
                 "z = (sign * score - center) / scale",
    "linear (fallback)": "dmos = b1 z + b2, z = (sign * score - center) / scale",
}
"""Each mapping in words, with the parameters as ``Mapping.params`` orders them (the
report's summary.json gives them per metric, with ``sign``: -1 for a lower-better metric,
whose scores are negated before the fit, else 1; so a reader can redraw the fitted curve)."""

#: Two stimuli per parameter of the logistic. With fewer, its five parameters follow the
#: noise: on 6 noisy stimuli it reached PLCC 0.9995, and P.1401's rmse had N - 5 = 1 degree
#: of freedom. A line is fitted instead.
MIN_LOGISTIC_STIMULI = 2 * N_PARAMS["logistic5"]


def logistic5(q: np.ndarray, b1: float, b2: float, b3: float, b4: float, b5: float) -> np.ndarray:
    """The 5-parameter logistic of VQEG / Sheikh et al. (2006)."""
    with np.errstate(over="ignore"):
        return b1 * (0.5 - 1.0 / (1.0 + np.exp(b2 * (q - b3)))) + b4 * q + b5


@dataclass
class Mapping:
    """A fitted monotone mapping from metric score to DMOS."""

    kind: str  # "logistic5" or "linear (fallback)"
    params: tuple[float, ...]
    center: float
    scale: float
    lower: tuple[float, ...] = ()
    upper: tuple[float, ...] = ()

    @property
    def n_params(self) -> int:
        """Degrees of freedom the mapping uses (P.1401's ``d``)."""
        return N_PARAMS[self.kind]

    def __call__(self, q: np.ndarray) -> np.ndarray:
        z = (np.asarray(q, dtype=float) - self.center) / self.scale
        if self.kind == "logistic5":
            return logistic5(z, *self.params)
        return self.params[0] * z + self.params[1]


def _monotone(values: np.ndarray, tol: float) -> bool:
    steps = np.diff(values)
    return bool((steps >= -tol).all() or (steps <= tol).all())


def fit_mapping(q: np.ndarray, y: np.ndarray) -> Mapping:
    """Fit the 5-parameter logistic (bounded, from a robust start) or fall back to a line."""
    q, y = np.asarray(q, dtype=float), np.asarray(y, dtype=float)
    center, scale = float(np.median(q)), float(np.std(q)) or 1.0
    z = (q - center) / scale
    slope, intercept = np.polyfit(z, y, 1) if len(z) >= 2 and np.ptp(z) > 0 else \
        (0.0, float(np.mean(y)))
    line = Mapping("linear (fallback)", (float(slope), float(intercept)), center, scale)
    if len(q) < MIN_LOGISTIC_STIMULI or np.ptp(z) == 0:
        return line
    yr = float(np.ptp(y)) or 1.0
    sign = 1.0 if slope >= 0 else -1.0
    # b1 and b4 share the sign of the trend (b2 > 0): monotone by construction, so the
    # logistic term and the linear term cannot cancel into a wiggly curve.
    b1 = (0.0, 10 * yr) if sign > 0 else (-10 * yr, 0.0)
    b4 = (0.0, yr) if sign > 0 else (-yr, 0.0)
    lower = (b1[0], 1e-2, float(z.min()), b4[0], float(y.min()) - 10 * yr)
    upper = (b1[1], 20.0, float(z.max()), b4[1], float(y.max()) + 10 * yr)
    # Starts over the range of the knee (b3) and of its steepness (b2): from one start the
    # fit can settle on a near-line (b2 at its floor) although a better logistic exists.
    knees = np.clip(np.quantile(z, [0.1, 0.3, 0.5, 0.7, 0.9]), lower[2], upper[2])
    starts = np.array([[sign * yr * f, b2, float(b3), 0.0, float(np.mean(y))]
                       for b2 in (0.3, 1.0, 3.0, 10.0) for b3 in knees for f in (1.0, 2.0)])
    params, sse = _lm_batch(np.tile(z, (len(starts), 1)), np.tile(y, (len(starts), 1)),
                            starts, np.array(lower), np.array(upper), iterations=400)
    grid = np.linspace(z.min(), z.max(), 200)

    def monotone(p: np.ndarray) -> bool:
        return _monotone(logistic5(grid, *p), 1e-9 * yr)

    good = np.isfinite(sse) & np.array([monotone(p) for p in params])
    if not good.any():
        log.info("no monotone logistic fit over the data; using a linear mapping")
        return line
    best = _polish(z, y, params, np.where(good, sse, np.inf), lower, upper, monotone)
    return Mapping("logistic5", tuple(float(p) for p in best), center, scale, lower, upper)


def _polish(z: np.ndarray, y: np.ndarray, params: np.ndarray, sse: np.ndarray,
            lower: tuple[float, ...], upper: tuple[float, ...],
            monotone: Callable[[np.ndarray], bool]) -> np.ndarray:
    """The best of the batch's fits after SciPy's bounded trust-region solver has refined
    the three best distinct ones (many starts end at the same optimum); a refinement counts
    only while it stays monotone."""
    best_i = int(np.argmin(sse))
    best, best_sse = params[best_i], float(sse[best_i])
    picked: list[np.ndarray] = []
    for i in np.argsort(sse):
        if not np.isfinite(sse[i]) or len(picked) == 3:
            break
        if any(np.allclose(params[i], q, rtol=1e-4, atol=1e-6) for q in picked):
            continue
        picked.append(params[i])
    for x0 in picked:
        with np.errstate(over="ignore"):
            res = least_squares(lambda p: logistic5(z, *p) - y, x0, bounds=(lower, upper),
                                method="trf", x_scale="jac", max_nfev=2000)
        cost = float(2.0 * res.cost)
        if np.isfinite(cost) and cost < best_sse and monotone(res.x):
            best, best_sse = res.x, cost
    return best


# -- many resamples at once -----------------------------------------------------------------
def _line_batch(z: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares line per row: predictions (B, n)."""
    zm, ym = z.mean(axis=1, keepdims=True), y.mean(axis=1, keepdims=True)
    zc = z - zm
    den = (zc * zc).sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = np.where(den > 0, (zc * (y - ym)).sum(axis=1, keepdims=True) / den, 0.0)
    return ym + slope * zc


def _logistic_batch(p: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values (B, n) and Jacobian (B, n, 5) of the logistic with per-row parameters (B, 5)."""
    b1, b2, b3, b4, b5 = (p[:, k:k + 1] for k in range(5))
    d = z - b3
    with np.errstate(over="ignore"):
        s = 1.0 / (1.0 + np.exp(b2 * d))
    ds = s * (1.0 - s)
    f = b1 * (0.5 - s) + b4 * z + b5
    jac = np.stack([0.5 - s, b1 * ds * d, -b1 * ds * b2, z, np.ones_like(z)], axis=-1)
    return f, jac


def _lm_batch(z: np.ndarray, y: np.ndarray, p: np.ndarray, lower: np.ndarray,
              upper: np.ndarray, *, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on every row at once (steps clipped to the bounds): the fitted
    parameters (B, 5) and sums of squared errors (B,)."""
    p = np.clip(p.astype(float), lower, upper)
    f, jac = _logistic_batch(p, z)
    sse = ((f - y) ** 2).sum(axis=1)
    lam = np.full(len(p), 1e-3)
    active = np.arange(len(p))
    eye = np.eye(5)
    for _ in range(iterations):
        if active.size == 0:
            break
        ja, za, ya, pa = jac[active], z[active], y[active], p[active]
        r = f[active] - ya
        jt = ja.transpose(0, 2, 1)
        jtj = jt @ ja
        g = (jt @ r[..., None])[..., 0]
        diag = np.maximum(np.einsum("bii->bi", jtj), 1e-12)
        a = jtj + (lam[active][:, None] * diag)[:, :, None] * eye
        try:
            step = np.linalg.solve(a, -g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = np.zeros_like(pa)
        cand = np.clip(pa + step, lower, upper)
        fc, jc = _logistic_batch(cand, za)
        sse_c = ((fc - ya) ** 2).sum(axis=1)
        old = sse[active]
        better = np.isfinite(sse_c) & (sse_c < old)
        upd = active[better]
        p[upd], f[upd], jac[upd], sse[upd] = cand[better], fc[better], jc[better], \
            sse_c[better]
        rel = np.where(better, (old - sse_c) / np.maximum(old, 1e-300), np.inf)
        lam[active] = np.where(better, lam[active] / 3.0, lam[active] * 4.0)
        done = (better & (rel < 1e-12)) | (lam[active] > 1e12)
        active = active[~done]
    return p, sse


def refit_batch(mapping: Mapping, q: np.ndarray, y: np.ndarray, *,
                iterations: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Refit ``mapping``'s form on every row of ``q``/``y`` (B, n); returns the predictions
    (B, n) and whether each row kept the logistic (False: line fallback)."""
    q, y = np.asarray(q, dtype=float), np.asarray(y, dtype=float)
    z = (q - mapping.center) / mapping.scale
    n_rows = z.shape[0]
    if mapping.kind != "logistic5":
        return _line_batch(z, y), np.zeros(n_rows, dtype=bool)
    p, _ = _lm_batch(z, y, np.tile(np.array(mapping.params), (n_rows, 1)),
                     np.array(mapping.lower), np.array(mapping.upper), iterations=iterations)
    f, _ = _logistic_batch(p, z)
    # The monotone-or-line rule of the full fit, row by row.
    grid = np.linspace(z.min(axis=1), z.max(axis=1), 60, axis=1)
    fg, _ = _logistic_batch(p, grid)
    steps = np.diff(fg, axis=1)
    tol = 1e-9 * np.maximum(np.ptp(y, axis=1, keepdims=True), 1.0)
    mono = (steps >= -tol).all(axis=1) | (steps <= tol).all(axis=1)
    ok = mono & np.isfinite(f).all(axis=1)
    if not ok.all():
        f = np.where(ok[:, None], f, _line_batch(z, y))
    return f, ok
