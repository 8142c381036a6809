"""Intraclass correlations from variance components, for incomplete (unbalanced) designs.

pingouin computes ICCs from the two-way ANOVA mean squares, which needs every rater to have
rated every stimulus; it silently drops the stimuli some rater skipped. Here the variance
components of the two-way model ``y = mu + target + rater + error`` are estimated by REML
(restricted maximum likelihood) on all cells present:

- ICC(2,*) (absolute agreement, raters random): ``s_t^2 / (s_t^2 + s_r^2 + s_e^2)`` for one
  rater, ``s_t^2 / (s_t^2 + (s_r^2 + s_e^2) / k)`` for the mean of k raters;
- ICC(3,*) (consistency, raters fixed): the same model with fixed rater effects,
  ``s_t^2 / (s_t^2 + s_e^2)`` and ``s_t^2 / (s_t^2 + s_e^2 / k)``.

On complete data REML gives the ANOVA estimates whenever those are positive, so the values
equal pingouin's (Shrout & Fleiss 1979; McGraw & Wong 1996); a component the ANOVA would
estimate below zero is 0 here. For an unbalanced design ``k`` is the mean number of raters per
stimulus. The likelihood is evaluated through the Woodbury identity on the
(stimuli + raters)-sized system, so one fit takes milliseconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize


@dataclass
class VarianceComponents:
    """REML variance components of the two-way model and the ICCs they give."""

    target: float
    rater: float
    error: float
    k: float
    consistency_target: float
    consistency_error: float
    log_ratios: np.ndarray | None = None

    def icc(self) -> dict[str, float]:
        t, r, e, k = self.target, self.rater, self.error, self.k
        tc, ec = self.consistency_target, self.consistency_error
        with np.errstate(invalid="ignore", divide="ignore"):
            return {
                "ICC(2,1)": t / (t + r + e),
                "ICC(2,k)": t / (t + (r + e) / k),
                "ICC(3,1)": tc / (tc + ec),
                "ICC(3,k)": tc / (tc + ec / k),
            }


class _Reml:
    """Profiled REML criterion for ``y = X beta + Z_t u_t [+ Z_r u_r] + e`` with
    ``u ~ N(0, s_e^2 gamma)``; stimuli (``Z_t``) are always random, raters (``Z_r``) random
    in model A and fixed (in ``X``) in model C.

    Each observation belongs to one stimulus, so ``Z_t' Z_t`` is diagonal and the
    (stimuli + raters) system is solved through the raters-sized Schur complement.
    """

    def __init__(self, y: np.ndarray, t_idx: np.ndarray, r_idx: np.ndarray, n_t: int,
                 n_r: int, raters_random: bool) -> None:
        self.raters_random = raters_random
        n = y.size
        self.nt = np.bincount(t_idx, minlength=n_t).astype(float)
        self.nr = np.bincount(r_idx, minlength=n_r).astype(float)
        inc = np.zeros((n_t, n_r))
        np.add.at(inc, (t_idx, r_idx), 1.0)
        self.inc = inc
        self.ty = np.bincount(t_idx, weights=y, minlength=n_t)
        self.ry = np.bincount(r_idx, weights=y, minlength=n_r)
        self.yty = float(y @ y)
        if raters_random:  # X = intercept
            self.p = 1
            self.tx, self.rx = self.nt[:, None], self.nr[:, None]
            self.xtx, self.xty = np.array([[float(n)]]), np.array([float(y.sum())])
        else:  # X = rater dummies
            self.p = n_r
            self.tx = inc
            self.xtx, self.xty = np.diag(self.nr), self.ry.copy()
        self.n = n

    def _parts(self, log_gamma: np.ndarray) -> tuple[float, float, float]:
        gt = np.exp(0.5 * log_gamma[0])
        a = 1.0 + gt * gt * self.nt  # diagonal block of M for the stimuli
        u_y, u_x = gt * self.ty, gt * self.tx  # G Z_t' y, G Z_t' X
        logdet_m = float(np.log(a).sum())
        if self.raters_random:
            gr = np.exp(0.5 * log_gamma[1])
            b = gt * gr * self.inc
            schur = np.diag(1.0 + gr * gr * self.nr) - b.T @ (b / a[:, None])
            chol = np.linalg.cholesky(schur)
            logdet_m += 2.0 * float(np.log(np.diag(chol)).sum())
            v = np.column_stack([gr * self.ry, gr * self.rx])  # G Z_r' [y X]
            u = np.column_stack([u_y, u_x])
            rhs = v - b.T @ (u / a[:, None])
            x2 = np.linalg.solve(schur, rhs)
            x1 = (u - b @ x2) / a[:, None]
            quad = u.T @ x1 + v.T @ x2  # [y X]' Z G M^-1 G Z' [y X]
        else:
            u = np.column_stack([u_y, u_x])
            quad = u.T @ (u / a[:, None])
        yhy = self.yty - quad[0, 0]
        xhx = self.xtx - quad[1:, 1:]
        xhy = self.xty - quad[1:, 0]
        beta = np.linalg.solve(xhx, xhy)
        ypy = float(yhy - xhy @ beta)
        logdet_x = float(np.linalg.slogdet(xhx)[1])
        return ypy, logdet_m, logdet_x

    def criterion(self, log_gamma: np.ndarray) -> float:
        try:
            ypy, ldm, ldx = self._parts(np.asarray(log_gamma, dtype=float))
        except np.linalg.LinAlgError:
            return np.inf
        if not ypy > 0:
            return np.inf
        return (self.n - self.p) * np.log(ypy) + ldm + ldx

    def fit(self, starts: tuple[np.ndarray, ...] | None = None) -> tuple[np.ndarray, float]:
        """Best log-gamma (ratios to the error variance) and the error variance."""
        if not self.raters_random:
            res = optimize.minimize_scalar(lambda x: self.criterion(np.array([x])),
                                           bounds=(-25.0, 12.0), method="bounded",
                                           options={"xatol": 1e-9})
            x = np.array([res.x])
        else:
            best = None
            for start in starts or (np.zeros(2), np.array([2.0, -3.0]), np.array([-3.0, 2.0])):
                res = optimize.minimize(self.criterion, start, method="L-BFGS-B",
                                        bounds=[(-25.0, 12.0)] * 2,
                                        options={"ftol": 1e-15, "gtol": 1e-10, "maxiter": 500})
                if best is None or res.fun < best.fun:
                    best = res
            x = best.x
        ypy, _, _ = self._parts(x)
        return x, ypy / (self.n - self.p)


def _ratio(lg: float) -> float:
    return 0.0 if lg <= -24.0 else float(np.exp(lg))


def variance_components(means: np.ndarray, start: np.ndarray | None = None
                        ) -> VarianceComponents:
    """REML variance components of a stimuli x raters table (NaN: not rated); ``start``
    (log variance ratios of model A) skips the multi-start search (bootstrap refits)."""
    ok = np.isfinite(means)
    t_idx, r_idx = np.nonzero(ok)
    y = means[ok].astype(float)
    n_t, n_r = means.shape
    scale = float(np.std(y)) or 1.0
    ys = (y - y.mean()) / scale
    lg_a, err_a = _Reml(ys, t_idx, r_idx, n_t, n_r, raters_random=True).fit(
        None if start is None else (start,))
    lg_c, err_c = _Reml(ys, t_idx, r_idx, n_t, n_r, raters_random=False).fit()
    s2 = scale * scale
    return VarianceComponents(
        log_ratios=lg_a, target=_ratio(lg_a[0]) * err_a * s2, rater=_ratio(lg_a[1]) * err_a * s2,
        error=err_a * s2, k=float(y.size) / float(ok.any(axis=1).sum()),
        consistency_target=_ratio(lg_c[0]) * err_c * s2, consistency_error=err_c * s2)


def icc_unbalanced(means: np.ndarray, *, n_boot: int = 200, seed: int = 0
                   ) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """REML ICCs of a stimuli x raters table with gaps, and 95% percentile CIs from a
    bootstrap over stimuli (seeded)."""
    keep = np.isfinite(means).sum(axis=1) >= 1
    means = means[keep][:, np.isfinite(means[keep]).any(axis=0)]
    components = variance_components(means)
    point = components.icc()
    rng = np.random.default_rng([seed, 31])
    draws = {k: [] for k in point}
    for _ in range(n_boot):
        sample = means[rng.integers(0, means.shape[0], means.shape[0])]
        sample = sample[:, np.isfinite(sample).any(axis=0)]
        if sample.shape[1] < 2:
            continue
        for key, val in variance_components(sample, components.log_ratios).icc().items():
            draws[key].append(val)
    ci = {}
    for key, vals in draws.items():
        v = np.array(vals, dtype=float)
        v = v[np.isfinite(v)]
        ci[key] = (float(np.percentile(v, 2.5)), float(np.percentile(v, 97.5))) if v.size \
            else (float("nan"), float("nan"))
    return point, ci
