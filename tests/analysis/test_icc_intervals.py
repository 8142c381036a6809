"""ICCs from REML variance components on unbalanced designs, and DMOS intervals from the
rater bootstrap (covariance of Q(v) and Q(ref) kept)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pingouin as pg
import pytest
from scipy import stats

from analysis.icc import variance_components
from analysis.inputs import ratings_from_frame
from analysis.intervals import estimator_weights, rater_bootstrap
from analysis.quality import drop_incomplete
from analysis.reliability import reliability
from analysis.scores import fit_scores
from analysis.synthetic import synthetic_study


def test_reml_equals_the_anova_iccs_on_complete_data() -> None:
    """Shrout & Fleiss (1979) table 2 (6 targets x 4 judges): ICC(2,k) = 0.620051 and
    ICC(3,k) = 0.909316 in their paper; and pingouin's 'icc' wine data."""
    sf = np.array([[9, 2, 5, 8], [6, 1, 3, 2], [8, 4, 6, 8], [7, 1, 2, 6], [10, 5, 6, 9],
                   [6, 2, 4, 7]], dtype=float)
    icc = variance_components(sf).icc()
    assert icc["ICC(2,k)"] == pytest.approx(0.620051, abs=1e-5)
    assert icc["ICC(3,k)"] == pytest.approx(0.909316, abs=1e-5)
    wine = pg.read_dataset("icc")
    table = pg.intraclass_corr(wine, "Wine", "Judge", "Scores").set_index("Type")["ICC"]
    ours = variance_components(wine.pivot(index="Wine", columns="Judge", values="Scores")
                               .to_numpy(float)).icc()
    assert ours["ICC(2,1)"] == pytest.approx(table["ICC(A,1)"], abs=1e-5)
    assert ours["ICC(3,k)"] == pytest.approx(table["ICC(C,k)"], abs=1e-5)


def test_reml_recovers_known_components_with_forty_percent_missing() -> None:
    rng = np.random.default_rng(0)
    t_sd, r_sd, e_sd, n_t, n_r = 10.0, 4.0, 6.0, 400, 8
    y = (rng.normal(0, t_sd, n_t)[:, None] + rng.normal(0, r_sd, n_r)[None, :]
         + rng.normal(0, e_sd, (n_t, n_r)))
    y[rng.random(y.shape) < 0.4] = np.nan
    vc = variance_components(y)
    assert vc.target == pytest.approx(t_sd ** 2, rel=0.15)
    assert vc.error == pytest.approx(e_sd ** 2, rel=0.1)
    truth = t_sd ** 2 / (t_sd ** 2 + r_sd ** 2 + e_sd ** 2)
    assert vc.icc()["ICC(2,1)"] == pytest.approx(truth, abs=0.06)
    assert vc.k == pytest.approx(np.isfinite(y).sum() / n_t)


def test_reliability_of_a_panel_with_a_partial_rater() -> None:
    st = synthetic_study(n_scenes=5, levels=2, n_raters=8, repetitions=1, noise_sd=6, seed=5,
                         special={"Xpart": "partial:0.55"})
    rs = ratings_from_frame(st.ratings, st.manifest)
    rel = reliability(rs, n_boot=30)
    assert rel.method.startswith("REML variance components")
    assert rel.n_targets < rel.n_stimuli  # stimuli every rater rated
    assert rel.complete_case is not None and rel.complete_case["n_stimuli"] == rel.n_targets
    lo, hi = rel.icc_ci["ICC(2,k)"]
    assert lo <= rel.icc["ICC(2,k)"] <= hi
    full = reliability(drop_incomplete(rs, 0.9))
    assert full.method.startswith("pingouin") and full.complete_case is None


def _panel(bias_sd: float, seed: int):
    st = synthetic_study(n_scenes=6, methods=("blur",), levels=3, n_raters=12, repetitions=2,
                         noise_sd=5, bias_sd=bias_sd, seed=seed)
    return st, ratings_from_frame(st.ratings, st.manifest)


def test_rater_bootstrap_matches_the_exact_t_interval_of_per_rater_differences() -> None:
    """For plain means on complete data the DMOS is the mean over raters of each rater's own
    DMOS; its exact Student interval is t(n-1) sd / sqrt(n). The bootstrap half-width with the
    small-sample correction must agree (4000 resamples)."""
    _, rs = _panel(bias_sd=8.0, seed=1)
    res = fit_scores(rs, "mos", n_boot=50)
    boot = rater_bootstrap(rs, estimator_weights(rs, res), 4000, seed=3)
    half = boot.halfwidth()
    means = rs.rater_means()
    ref = rs.reference_index()
    for e in np.flatnonzero(~rs.hidden_reference_mask):
        d = means[e] - means[ref[e]] + 100
        exact = stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / np.sqrt(d.size)
        assert half[e] == pytest.approx(exact, rel=0.06)
        assert boot.dmos_full[e] == pytest.approx(d.mean())


def test_quadrature_ignores_the_covariance_the_bootstrap_keeps() -> None:
    """With strong rater biases Q(v) and Q(ref) move together: quadrature of their CIs is
    far wider than the interval of their difference."""
    _, rs = _panel(bias_sd=12.0, seed=2)
    res = fit_scores(rs, "mos", n_boot=1000)
    cond = ~rs.hidden_reference_mask
    ref = rs.reference_index()[cond]
    quad = np.sqrt(res.quality_halfwidth[cond] ** 2 + res.quality_halfwidth[ref] ** 2)
    assert np.median(res.dmos_halfwidth[cond] / quad) < 0.7
    assert (res.dmos_halfwidth[rs.hidden_reference_mask] == 0).all()  # the anchor


def test_mle_weights_follow_the_model() -> None:
    _, rs = _panel(bias_sd=5.0, seed=4)
    res = fit_scores(rs, "p910", n_boot=200)
    w = estimator_weights(rs, res)
    v = np.maximum(res.rater_inconsistency, 0.02 * 100)
    np.testing.assert_allclose(w.weight[0], 1 / v ** 2)
    np.testing.assert_allclose(w.bias, res.rater_bias)
    # the bootstrap world's DMOS is close to the model's own DMOS
    cond = ~rs.hidden_reference_mask
    assert np.max(np.abs(res.bootstrap.dmos_full[cond] - res.dmos[cond])) < 1.0
    assert pd.Series(res.dmos_halfwidth[cond]).between(0.5, 15).all()
