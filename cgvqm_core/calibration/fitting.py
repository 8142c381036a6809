"""Fitting omega and alpha to human scores: the upstream objective, vectorised and fast.

The upstream recipe (Jindal et al. 2025) minimises, summed over datasets, ``1 - |PLCC|``
between ``s_v = alpha * max_p sum_c |omega_c| m_vpc`` and the human scores, with Adam (learning
rate 1e-6 for omega, 1.0 for alpha) for 100k steps, keeping the best parameters. Written with
autograd this costs a few milliseconds per step; here one step is a handful of numpy
operations on small arrays, because

* the gradient is analytic (it equals torch autograd's, which the tests check),
* Adam is applied by hand with torch's exact update rule (also checked against torch),
* the max over patches is evaluated only on *candidate* patches. With ``w = |omega|`` and
  ``m >= 0``, a patch's error moves by at most ``||m_p||_1 * max_c |w_c - w0_c|`` away from
  its value at an earlier ``w0``. Each video keeps the few patches that can be its maximum;
  at every step the dropped patches' bound is compared with the exact maximum over the kept
  ones, and a video whose bound is no longer below it has all its patches re-evaluated
  (only that video). The result is exact, not an approximation.

Several independent fits ("rows": one per split) run in the same loop, each with its own
train/validation membership, so repeated validation costs one loop.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from tqdm.auto import tqdm

from ..errors import CGVQMError

log = logging.getLogger(__name__)

Objective = Literal["plcc", "plcc-signed", "nmse"]
Pooling = Literal["max", "mean"]
Select = Literal["train", "val", "last"]



@dataclass(frozen=True)
class FitConfig:
    """How to fit: the upstream defaults, plus the options this tool adds.

    ``objective``: "plcc" (upstream: sum over datasets of 1 - |PLCC|; the scale of alpha and
    omega is free, and so is the sign: a fit may end up with scores that fall as quality
    rises), "plcc-signed" (sum of 1 - PLCC(q, target) with q = 100 - s: the same, but only
    the right direction counts) or "nmse" (sum over datasets of the mean squared error
    between q and the target, divided by the target's variance: fits the scale too). The
    last two need the target on the quality direction (100 = imperceptible).

    ``select``: which step's parameters are kept: the lowest training loss (upstream), the
    lowest validation loss (needs validation videos), or the last step (a fixed step count).
    Test videos are never looked at.
    """

    steps: int = 100_000
    lr_omega: float = 1e-6
    lr_alpha: float = 1.0
    alpha_init: float = 1000.0
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-8
    objective: Objective = "plcc"
    pooling: Pooling = "max"
    select: Select = "train"
    seed: int = 0
    refresh_steps: int = 256  # candidate-patch margin in units of lr_omega (speed, not result)
    history_every: int = 1000
    show_progress: bool = True


@dataclass
class FitResult:
    """Per row: the selected omega/alpha, at which step, and the loss history."""

    omega: np.ndarray  # (R, N) float64, signs kept (the metric uses |omega|)
    alpha: np.ndarray  # (R,)
    best_step: np.ndarray  # (R,) int: step whose parameters were kept
    best_loss: np.ndarray  # (R,) the selection loss at that step
    history: dict[str, list] = field(default_factory=dict)  # step, train_loss, val_loss
    refreshes: int = 0  # full re-evaluations of one video's patches (a speed figure)
    config: FitConfig | None = None


def init_omega(n_channels: int, n_rows: int, seed: int) -> np.ndarray:
    """Upstream's start: uniform random in [0, 1), normalised to sum 1 (one row per fit)."""
    rng = np.random.default_rng(seed)
    w = rng.random((n_rows, n_channels))
    return w / w.sum(axis=1, keepdims=True)


#: at most this many candidate patches per video after a re-evaluation (speed only)
KEEP_TARGET = 4
#: candidate arrays of the rows fitted in one loop stay under this size (speed only)
ROW_BUDGET_BYTES = 4 << 20


class _Candidates:
    """Per video and row, the patches that can still hold the video's maximum error.

    At a full evaluation of video ``v`` for row ``r`` every patch error ``e0`` is computed at
    ``w0 = |omega_r|``; patches that cannot reach the maximum while ``|w - w0|`` stays within
    ``threshold`` (max norm) are dropped. Afterwards a dropped patch's error is at most
    ``max(e0_dropped) + max(||m_dropped||_1) * D``, where ``D`` (the summed max-norm movement
    of ``w`` since then) bounds ``max_c |w_c - w0_c|``. While that stays below the exact
    maximum over the kept patches the max is exact; where it does not, that video is
    re-evaluated in full (only that video, only that row).
    """

    def __init__(self, M: np.ndarray, pooling: Pooling, threshold: float, n_rows: int) -> None:
        self.M = M  # (V, P, N) float32, zero-padded
        self.pooling = pooling
        self.threshold = threshold
        V, _, N = M.shape
        self.l1 = M.sum(axis=2, dtype=np.float64)  # (V, P): ||m_p||_1 (m >= 0)
        self.Mc = np.zeros((n_rows, V, 1, N), dtype=np.float32)  # (R, V, C, N)
        self.ex_e0 = np.full((n_rows, V), np.inf)  # largest e0 among dropped patches
        self.ex_l1 = np.zeros((n_rows, V))  # largest ||m||_1 among dropped patches
        self.moved0 = np.zeros((n_rows, V))  # movement counter at the last evaluation
        self.moved = np.zeros(n_rows)  # sum over steps of max_c |w_t - w_{t-1}|
        self.w_prev: np.ndarray | None = None
        self.count = 0  # videos re-evaluated in full, summed over rows
        self.n_keep = np.ones((n_rows, V), dtype=np.int64)

    def set_mean(self, counts: np.ndarray) -> None:
        mean = self.M.sum(axis=1, dtype=np.float64) / counts[:, None]  # (V, N)
        self.Mc = np.ascontiguousarray(np.broadcast_to(mean[None, :, None, :], self.Mc.shape),
                                       dtype=np.float32)
        self.ex_e0[:] = -np.inf

    def track(self, w: np.ndarray) -> None:
        """Record the movement of w = |omega| since the previous call."""
        if self.w_prev is not None:
            self.moved += np.abs(w - self.w_prev).max(axis=1)
        self.w_prev = w.copy()

    def stale(self, emax: np.ndarray) -> np.ndarray:
        """(R, V) bool: where a dropped patch might now exceed the kept maximum."""
        bound = self.ex_e0 + self.ex_l1 * (self.moved[:, None] - self.moved0)
        return bound > emax

    def refresh(self, w: np.ndarray, where: np.ndarray, arg: np.ndarray | None = None,
                emax: np.ndarray | None = None) -> None:
        """Re-evaluate all patches of the (row, video) pairs in ``where`` (R, V) bool; also
        update their entries of ``arg`` (position in the kept list) and ``emax`` in place."""
        for r in np.flatnonzero(where.any(axis=1)):
            vs = np.flatnonzero(where[r])
            # (k, P, N); one video (the usual case) is a view, not a copy
            Msub = self.M[vs[0]][None] if len(vs) == 1 else self.M[vs]
            e0 = (Msub @ w[r].astype(np.float32)).astype(np.float64)  # (k, P)
            l1 = self.l1[vs]
            # the widest margin (threshold, halved up to 12 times, then 0) that keeps at most
            # KEEP_TARGET patches: wide margins mean fewer re-evaluations, narrow fewer columns
            thetas = self.threshold * np.append(0.5 ** np.arange(13), 0.0)  # (K,)
            slack = l1[None] * thetas[:, None, None]  # (K, k, P)
            keeps = (e0 + slack >= (e0 - slack).max(axis=2, keepdims=True)) & (l1 > 0)
            pick = np.argmax(keeps.sum(axis=2) <= KEEP_TARGET, axis=0)  # first that fits
            keep = keeps[pick, np.arange(len(vs))]
            best = e0.argmax(axis=1)
            keep[np.arange(len(vs)), best] = True
            n_keep = keep.sum(axis=1)
            C = int(n_keep.max())
            if self.Mc.shape[2] < C:
                grown = np.empty((*self.Mc.shape[:2], C, self.Mc.shape[3]), dtype=np.float32)
                grown[:, :, : self.Mc.shape[2]] = self.Mc
                grown[:, :, self.Mc.shape[2]:] = self.Mc[:, :, :1]  # duplicates: max unchanged
                self.Mc = grown
            Cm = self.Mc.shape[2]
            order = np.argsort(~keep, axis=1, kind="stable")[:, :Cm]
            if order.shape[1] < Cm:
                order = np.pad(order, ((0, 0), (0, Cm - order.shape[1])), mode="edge")
            idx = np.where(np.arange(Cm)[None, :] < n_keep[:, None], order, best[:, None])
            self.Mc[r, vs] = Msub[np.arange(len(vs))[:, None], idx]
            # e0 was summed in float32: a relative 1e-4 covers its rounding
            self.ex_e0[r, vs] = np.where(keep, -np.inf, e0).max(axis=1) \
                + 1e-4 * np.abs(e0).max(axis=1)
            self.ex_l1[r, vs] = np.where(keep, 0.0, l1).max(axis=1)
            self.moved0[r, vs] = self.moved[r]
            self.n_keep[r, vs] = n_keep
            self.count += len(vs)
            if arg is not None and emax is not None:
                rank = np.cumsum(keep, axis=1) - 1  # position of each kept patch in the list
                arg[r, vs] = rank[np.arange(len(vs)), best]
                emax[r, vs] = e0[np.arange(len(vs)), best]
        widest = int(self.n_keep.max())
        if widest < self.Mc.shape[2] // 2:  # kept patches come first: drop unused columns
            self.Mc = np.ascontiguousarray(self.Mc[:, :, :widest])


class _Groups:
    """Masks of (row, dataset, video) membership for one subset (train or validation)."""

    def __init__(self, member: np.ndarray, groups: np.ndarray, n_groups: int, y: np.ndarray):
        onehot = groups[None, :] == np.arange(n_groups)[:, None]  # (D, V)
        self.W = (member[:, None, :] & onehot[None]).astype(np.float64)  # (R, D, V)
        self.n = self.W.sum(axis=2)  # (R, D)
        self.active = self.n > 0
        n_safe = np.maximum(self.n, 1.0)
        self.ybar = (self.W * y).sum(axis=2) / n_safe
        self.dy = self.W * (y[None, None, :] - self.ybar[..., None])  # (R, D, V), masked
        self.Syy = (self.dy**2).sum(axis=2)
        self.n_safe = n_safe


def _plcc_and_grad(s: np.ndarray, g: _Groups, need_grad: bool, signed: bool = False
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Loss sum_d (1 - |r_d|) per row, its gradient w.r.t. s (R, V), and r (R, D), with
    r_d = PLCC(s, y) on dataset d; ``signed``: sum_d (1 + r_d) = sum_d (1 - PLCC(100 - s, y))."""
    sbar = np.matmul(g.W, s[:, :, None])[..., 0] / g.n_safe  # (R, D)
    ds = g.W * (s[:, None, :] - sbar[..., None])  # (R, D, V), masked
    Sxy = np.matmul(g.dy, s[:, :, None])[..., 0]  # dy is centred and masked
    Sxx = np.einsum("rdv,rdv->rd", ds, ds)
    denom = np.sqrt(Sxx * g.Syy)
    ok = g.active & (denom > 0)
    r = np.where(ok, Sxy / np.where(ok, denom, 1.0), 0.0)
    loss = np.where(g.active, 1.0 + r if signed else 1.0 - np.abs(r), 0.0).sum(axis=1)
    if not need_grad:
        return loss, None, r
    # dr_d/ds_v = dy_dv / sqrt(Sxx Syy) - r_d ds_dv / Sxx, summed over d with the loss's sign
    a = np.where(ok, 1.0 / np.where(ok, denom, 1.0), 0.0)
    b = np.where(ok, r / np.where(ok, Sxx, 1.0), 0.0)
    sign = np.ones_like(r) if signed else -np.sign(r)
    grad = (np.matmul((sign * a)[:, None, :], g.dy)[:, 0, :]
            - np.matmul((sign * b)[:, None, :], ds)[:, 0, :])
    return loss, grad, r


def _nmse_and_grad(s: np.ndarray, g: _Groups, y: np.ndarray, need_grad: bool
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Loss sum_d mean_v((100 - s_v) - y_v)^2 / var_d(y) per row, and its gradient."""
    var = np.where(g.active, g.Syy / g.n_safe, 1.0)
    var = np.where(var > 0, var, 1.0)
    resid = g.W * ((100.0 - s)[:, None, :] - y[None, None, :])  # (R, D, V)
    scale = 1.0 / (g.n_safe * var)  # (R, D)
    loss = ((resid**2).sum(axis=2) * scale).sum(axis=1)
    rmse = np.sqrt((resid**2).sum(axis=2) / g.n_safe)
    if not need_grad:
        return loss, None, rmse
    grad = (-2.0 * resid * scale[..., None]).sum(axis=1)
    return loss, grad, rmse


class _Adam:
    """torch.optim.Adam's default update (no weight decay, no amsgrad), for numpy arrays."""

    def __init__(self, shape: tuple[int, ...], lr: float, betas: tuple[float, float],
                 eps: float) -> None:
        self.lr, (self.b1, self.b2), self.eps = lr, betas, eps
        self.m = np.zeros(shape)
        self.v = np.zeros(shape)
        self.t = 0

    def step(self, p: np.ndarray, grad: np.ndarray) -> None:
        self.t += 1
        self.m *= self.b1
        self.m += (1.0 - self.b1) * grad
        self.v *= self.b2
        self.v += (1.0 - self.b2) * grad * grad
        bc1 = 1.0 - self.b1**self.t
        bc2_sqrt = np.sqrt(1.0 - self.b2**self.t)
        p -= (self.lr / bc1) * self.m / (np.sqrt(self.v) / bc2_sqrt + self.eps)


class _Objective:
    """The loss of every row at the current omega and alpha, and its gradient w.r.t. the
    scores s = alpha * e (e: each video's pooled patch error, exact through the candidates)."""

    def __init__(self, cand: _Candidates, tr: _Groups, va: _Groups | None, y: np.ndarray,
                 config: FitConfig, rows: np.ndarray, vids: np.ndarray) -> None:
        self.cand, self.tr, self.va, self.y, self.config = cand, tr, va, y, config
        self.rows, self.vids = rows, vids  # (R, 1) and (1, V) indices

    def patch_max(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per row and video, the candidate index of the maximal patch and its error."""
        Mc = self.cand.Mc
        Rr, Vv, C, Nn = Mc.shape
        w32 = w.astype(np.float32)[:, :, None]
        e = np.matmul(Mc.reshape(Rr, Vv * C, Nn), w32).reshape(Rr, Vv, C)
        arg = e.argmax(axis=2)
        return arg, e[self.rows, self.vids, arg].astype(np.float64)

    def __call__(self, omega: np.ndarray, alpha: np.ndarray, need_grad: bool
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None,
                            np.ndarray | None]:
        """(arg, e, training loss, its gradient w.r.t. s or None, validation loss or None)."""
        config, y = self.config, self.y
        w = np.abs(omega)
        self.cand.track(w)
        arg, emax = self.patch_max(w)
        stale = self.cand.stale(emax)
        if stale.any():
            self.cand.refresh(w, stale, arg, emax)
        s = alpha[:, None] * emax
        signed = config.objective == "plcc-signed"
        if config.objective == "nmse":
            loss, gs, _ = _nmse_and_grad(s, self.tr, y, need_grad)
        else:
            loss, gs, _ = _plcc_and_grad(s, self.tr, need_grad, signed)
        vloss = None
        if self.va is not None and config.select == "val":
            vloss = (_nmse_and_grad(s, self.va, y, False)[0] if config.objective == "nmse"
                     else _plcc_and_grad(s, self.va, False, signed)[0])
        return arg, emax, loss, gs, vloss


class _Kept:
    """Per row, the parameters kept so far and the step and loss they were kept at."""

    def __init__(self, omega: np.ndarray, alpha: np.ndarray) -> None:
        self.loss = np.full(len(alpha), np.inf)
        self.omega, self.alpha = omega.copy(), alpha.copy()
        self.step = np.zeros(len(alpha), dtype=np.int64)

    def offer(self, step: int, sel: np.ndarray | None, loss: np.ndarray, last: bool,
              omega: np.ndarray, alpha: np.ndarray) -> None:
        """Keep the rows whose selection loss ``sel`` improved (``sel`` None: keep the last)."""
        if sel is None:
            better = np.full(len(alpha), last)
            sel = loss
        else:
            better = sel < self.loss
        if better.any():
            self.loss = np.where(better, sel, self.loss)
            self.omega[better] = omega[better]
            self.alpha[better] = alpha[better]
            self.step[better] = step


def _start_omega(N: int, R: int, config: FitConfig, omega0: np.ndarray | None) -> np.ndarray:
    return (init_omega(N, R, config.seed) if omega0 is None
            else np.array(np.broadcast_to(omega0, (R, N)), dtype=np.float64))


def _fit_in_chunks(M: np.ndarray, counts: np.ndarray, y: np.ndarray, groups: np.ndarray,
                   train: np.ndarray, val: np.ndarray | None, config: FitConfig,
                   omega0: np.ndarray | None, chunk: int) -> FitResult:
    """:func:`fit` on ``chunk`` rows at a time, merged (the same results as one loop)."""
    R, N = train.shape[0], M.shape[2]
    start = _start_omega(N, R, config, omega0)
    parts = [fit(M, counts, y, groups, train[i:i + chunk],
                 val=None if val is None else np.atleast_2d(val)[i:i + chunk],
                 config=config, omega0=start[i:i + chunk]) for i in range(0, R, chunk)]
    history: dict[str, list] = {"step": parts[0].history["step"]}
    for key in ("train_loss", "val_loss"):
        history[key] = [None if parts[0].history[key][j] is None else
                        [x for p in parts for x in p.history[key][j]]
                        for j in range(len(history["step"]))]
    return FitResult(np.concatenate([p.omega for p in parts]),
                     np.concatenate([p.alpha for p in parts]),
                     np.concatenate([p.best_step for p in parts]),
                     np.concatenate([p.best_loss for p in parts]), history,
                     sum(p.refreshes for p in parts), config)


def fit(
    M: np.ndarray,
    counts: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    train: np.ndarray,
    *,
    val: np.ndarray | None = None,
    config: FitConfig = FitConfig(),
    omega0: np.ndarray | None = None,
) -> FitResult:
    """Fit one omega/alpha per row of ``train`` (R, V) bool on the feature cache ``M``.

    ``M`` (V, P, N) float32 holds each video's per-patch, per-channel mean squared feature
    difference, zero-padded beyond ``counts[v]`` patches; ``y`` (V,) the human target;
    ``groups`` (V,) the dataset index of each video (the loss is summed over datasets).
    ``val`` (R, V) bool: validation videos (needed for ``select="val"``).
    """
    M = np.ascontiguousarray(M, dtype=np.float32)
    V, _, N = M.shape
    y = np.asarray(y, dtype=np.float64)
    groups = np.asarray(groups, dtype=np.int64)
    train = np.atleast_2d(np.asarray(train, dtype=bool))
    R = train.shape[0]
    # rows share one loop (less Python overhead) while their candidate arrays stay small
    # enough for the CPU caches; beyond that, rows are fitted in chunks (same results)
    chunk = max(1, ROW_BUDGET_BYTES // (V * KEEP_TARGET * N * 4))
    if chunk < R:
        return _fit_in_chunks(M, counts, y, groups, train, val, config, omega0, chunk)
    n_groups = int(groups.max()) + 1 if V else 0
    if config.select == "val" and (val is None or not np.asarray(val).any(axis=1).all()):
        raise CGVQMError("select='val' needs validation videos in every row")
    tr = _Groups(train, groups, n_groups, y)
    va = _Groups(np.atleast_2d(np.asarray(val, dtype=bool)), groups, n_groups, y) \
        if val is not None else None

    omega = _start_omega(N, R, config, omega0)
    alpha = np.full(R, float(config.alpha_init))
    opt_w = _Adam((R, N), config.lr_omega, config.betas, config.eps)
    opt_a = _Adam((R,), config.lr_alpha, config.betas, config.eps)
    cand = _Candidates(M, config.pooling, config.lr_omega * config.refresh_steps, R)
    if config.pooling == "mean":
        cand.set_mean(np.maximum(np.asarray(counts, dtype=np.float64), 1.0))
    rows = np.arange(R)[:, None]
    vids = np.arange(V)[None, :]
    evaluate = _Objective(cand, tr, va, y, config, rows, vids)
    kept = _Kept(omega, alpha)
    hist: dict[str, list] = {"step": [], "train_loss": [], "val_loss": []}

    steps = int(config.steps)
    bar = tqdm(total=steps, desc=f"fit ({R} split{'s' if R != 1 else ''})", unit="step",
               disable=not config.show_progress, mininterval=0.5, leave=False)
    for step in range(steps + 1):
        last = step == steps
        arg, emax, loss, gs, vloss = evaluate(omega, alpha, need_grad=not last)
        sel = {"train": loss, "val": vloss, "last": None}[config.select]
        kept.offer(step, sel, loss, last, omega, alpha)
        if step % config.history_every == 0 or last:
            hist["step"].append(step)
            hist["train_loss"].append(loss.tolist())
            hist["val_loss"].append(None if vloss is None else vloss.tolist())
        if last:
            break
        Msel = cand.Mc[rows, vids, arg]  # (R, V, N): each video's maximal patch
        g_mc = np.matmul(gs.astype(np.float32)[:, None, :], Msel)[:, 0, :]
        g_omega = alpha[:, None] * g_mc.astype(np.float64) * np.sign(omega)
        g_alpha = (gs * emax).sum(axis=1)
        opt_w.step(omega, g_omega)
        opt_a.step(alpha, g_alpha)
        if (step + 1) % 500 == 0:
            bar.update(500)
    bar.update(steps - bar.n)
    bar.close()
    log.debug("fit: %d steps, %d full re-evaluations of a video", steps, cand.count)
    return FitResult(kept.omega, kept.alpha, kept.step, kept.loss, hist, cand.count, config)


def pooled_errors(M: np.ndarray, counts: np.ndarray, omega: np.ndarray,
                  pooling: Pooling = "max") -> np.ndarray:
    """Per video, the pooled patch error max_p (or mean_p) of sum_c |omega_c| m_pc (no alpha).

    ``omega`` (N,) or (R, N); returns (V,) or (R, V).
    """
    w = np.abs(np.atleast_2d(np.asarray(omega, dtype=np.float64))).astype(np.float32)
    V, P, N = M.shape
    flat = np.ascontiguousarray(M, dtype=np.float32).reshape(V * P, N)
    e = (flat @ w.T).astype(np.float64).T.reshape(-1, V, P)
    if pooling == "max":
        valid = np.arange(P)[None, :] < np.asarray(counts)[:, None]
        out = np.where(valid[None], e, -np.inf).max(axis=2)
    else:
        out = e.sum(axis=2) / np.maximum(np.asarray(counts, dtype=np.float64), 1.0)[None]
    return out[0] if np.ndim(omega) == 1 else out
