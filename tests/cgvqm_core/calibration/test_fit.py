"""The fast fit against a plain torch autograd + torch.optim.Adam loop, and truth recovery."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cgvqm_core.calibration import CalibrationData, FitConfig, fit, pooled_errors, scene_split
from cgvqm_core.calibration.fitting import init_omega
from cgvqm_core.calibration.objective import calibration_loss
from cgvqm_core.calibration.stats import correlations


def _small(seed: int = 1):
    rng = np.random.default_rng(seed)
    V, P, N = 30, 8, 20
    M = (rng.gamma(1, 1, (V, P, 1)) * rng.gamma(2, 1, (V, P, N))).astype(np.float32)
    counts = rng.integers(3, P + 1, V)
    for v in range(V):
        M[v, counts[v]:] = 0
    y = rng.normal(50, 10, V)
    groups = rng.integers(0, 2, V)
    return M, counts, y, groups


@pytest.mark.parametrize("objective,pooling", [("plcc", "max"), ("plcc-signed", "max"),
                                               ("nmse", "max"), ("plcc", "mean")])
def test_fit_follows_torch_adam_on_the_reference_loss(objective, pooling):
    """Same start, same steps: the hand-written gradient + Adam equal autograd + torch Adam.

    A large omega learning rate makes the patch holding each video's maximum change during
    the run, so the candidate-patch bookkeeping is exercised (it must stay exact)."""
    M, counts, y, groups = _small()
    nmse = objective == "nmse"
    cfg = FitConfig(steps=150, lr_omega=3e-3, lr_alpha=1e-2 if nmse else 1.0,
                    alpha_init=10.0 if nmse else 1000.0, select="last",
                    objective=objective, pooling=pooling, show_progress=False, seed=3)
    res = fit(M, counts, y, groups, np.ones((1, len(y)), bool), config=cfg)

    omega = torch.tensor(init_omega(M.shape[2], 1, 3)[0], requires_grad=True)
    alpha = torch.tensor(cfg.alpha_init, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([{"params": [omega], "lr": cfg.lr_omega},
                            {"params": [alpha], "lr": cfg.lr_alpha}])
    Mt, ct = torch.tensor(M, dtype=torch.float64), torch.tensor(counts)
    yt, gt = torch.tensor(y), torch.tensor(groups)
    argmax_changed = False
    first_arg = None
    for _ in range(cfg.steps):
        opt.zero_grad()
        loss = calibration_loss(Mt, ct, yt, gt, omega, alpha, objective=objective,
                                pooling=pooling)
        loss.backward()
        opt.step()
        arg = (Mt @ omega.detach().abs()).argmax(1)
        first_arg = arg if first_arg is None else first_arg
        argmax_changed |= bool((arg != first_arg).any())
    final = calibration_loss(Mt, ct, yt, gt, omega, alpha, objective=objective, pooling=pooling)
    if pooling == "max":
        assert argmax_changed
    np.testing.assert_allclose(res.omega[0], omega.detach().numpy(), rtol=1e-4, atol=1e-6)
    assert res.alpha[0] == pytest.approx(alpha.item(), rel=1e-6)
    assert res.best_loss[0] == pytest.approx(final.item(), rel=1e-5)
    assert res.best_step[0] == cfg.steps


def test_rows_are_independent_fits():
    """Fitting several splits in one loop gives each the result of fitting it alone."""
    M, counts, y, groups = _small(2)
    rng = np.random.default_rng(0)
    train = rng.random((3, len(y))) < 0.6
    cfg = FitConfig(steps=100, lr_omega=1e-3, show_progress=False, seed=5)
    together = fit(M, counts, y, groups, train, config=cfg)
    start = init_omega(M.shape[2], 3, 5)
    for r in range(3):
        alone = fit(M, counts, y, groups, train[r:r + 1], config=cfg, omega0=start[r])
        np.testing.assert_allclose(together.omega[r], alone.omega[0], rtol=1e-6, atol=1e-9)
        assert together.best_step[r] == alone.best_step[0]


def test_best_step_is_chosen_by_validation_loss_when_asked():
    M, counts, y, groups = _small(3)
    V = len(y)
    train = np.zeros((1, V), bool)
    train[0, : V // 2] = True
    val = ~train
    cfg = FitConfig(steps=300, lr_omega=1e-2, select="val", show_progress=False,
                    history_every=1)
    res = fit(M, counts, y, groups, train, val=val, config=cfg)
    vloss = np.array([v[0] for v in res.history["val_loss"]])
    assert res.best_step[0] == int(np.argmin(vloss))
    assert res.best_loss[0] == pytest.approx(vloss.min())


def _split_fit(synth, ratio, seeds, steps=1500):
    data = CalibrationData(synth.items, synth.M, synth.counts)
    splits = [scene_split(synth.items["scene"].tolist(), synth.items["dataset"].tolist(),
                          ratio, s) for s in seeds]
    res = fit(synth.M, synth.counts, data.y, data.groups, np.stack([s.train for s in splits]),
              config=FitConfig(steps=steps, lr_omega=1e-3, show_progress=False))
    return data, splits, res


def test_fit_recovers_known_weights_near_the_noise_ceiling(synth):
    """Human scores generated from known channel weights + noise: on held-out scenes the
    fitted metric approaches the noise ceiling (the true quality's own PLCC with the noisy
    scores) and beats uniform weights by far."""
    data, splits, res = _split_fit(synth, 0.5, range(4))
    E = pooled_errors(synth.M, synth.counts, res.omega)
    E_uniform = pooled_errors(synth.M, synth.counts, np.ones(synth.M.shape[2]))
    y = data.y
    for r, split in enumerate(splits):
        te = split.test
        ceiling = correlations(synth.quality[te], y[te])["plcc"]
        fitted = correlations(100 - res.alpha[r] * E[r][te], y[te])["plcc"]
        uniform = correlations(100 - E_uniform[te], y[te])["plcc"]
        assert ceiling > 0.95
        assert fitted > ceiling - 0.03, (fitted, ceiling)
        assert fitted > uniform + 0.3, (fitted, uniform)


def test_fit_with_the_papers_20_percent_still_beats_uniform(synth):
    data, splits, res = _split_fit(synth, 0.2, range(4))
    E = pooled_errors(synth.M, synth.counts, res.omega)
    E_uniform = pooled_errors(synth.M, synth.counts, np.ones(synth.M.shape[2]))
    y = data.y
    fitted = [correlations(-E[r][s.test], y[s.test])["plcc"] for r, s in enumerate(splits)]
    uniform = [correlations(-E_uniform[s.test], y[s.test])["plcc"] for s in splits]
    assert np.mean(fitted) > np.mean(uniform) + 0.15


def test_pooled_errors_matches_a_direct_loop(synth):
    w = np.random.default_rng(0).normal(size=synth.M.shape[2])
    got = pooled_errors(synth.M, synth.counts, w, "max")
    got_mean = pooled_errors(synth.M, synth.counts, w, "mean")
    for v in range(len(synth.counts)):
        e = [float(np.dot(synth.M[v, p].astype(np.float64), np.abs(w)))
             for p in range(synth.counts[v])]
        assert got[v] == pytest.approx(max(e), rel=1e-5)
        assert got_mean[v] == pytest.approx(np.mean(e), rel=1e-5)


def test_fitting_rows_in_chunks_changes_nothing(monkeypatch):
    import cgvqm_core.calibration.fitting as fitting

    M, counts, y, groups = _small(4)
    rng = np.random.default_rng(1)
    train = rng.random((5, len(y))) < 0.5
    cfg = FitConfig(steps=200, lr_omega=1e-3, show_progress=False, select="val",
                    history_every=50)
    whole = fit(M, counts, y, groups, train, val=~train, config=cfg)
    row_bytes = M.shape[0] * fitting.KEEP_TARGET * M.shape[2] * 4
    monkeypatch.setattr(fitting, "ROW_BUDGET_BYTES", 2 * row_bytes)  # chunks of 2, 2, 1
    chunked = fit(M, counts, y, groups, train, val=~train, config=cfg)
    np.testing.assert_array_equal(whole.omega, chunked.omega)
    np.testing.assert_array_equal(whole.best_step, chunked.best_step)
    assert whole.history == chunked.history
