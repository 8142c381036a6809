"""ICC reference values, inter-rater matrix and intra-rater repeatability."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from analysis.data import RatingSet
from analysis.reliability import icc_from_long, reliability, repetition_correlation

# Shrout & Fleiss (1979), Table 2: 6 targets rated by 4 judges.
SHROUT_FLEISS = np.array([
    [9, 2, 5, 8],
    [6, 1, 3, 2],
    [8, 4, 6, 8],
    [7, 1, 2, 6],
    [10, 5, 6, 9],
    [6, 2, 4, 7],
], dtype=float)


def _rating_set(scores: np.ndarray) -> RatingSet:
    n = scores.shape[0]
    table = pd.DataFrame({"reference": [f"R{i}" for i in range(n)],
                          "scene": [f"R{i}" for i in range(n)], "method": "x",
                          "level": pd.array([1] * n, dtype="Int64"),
                          "is_hidden_reference": False},
                         index=pd.Index([f"S{i}" for i in range(n)], name="stimulus"))
    return RatingSet(table, [f"J{j}" for j in range(scores.shape[1])], scores, 0, 10, 10)


def test_icc_shrout_fleiss() -> None:
    rel = reliability(_rating_set(SHROUT_FLEISS[:, :, None]))
    assert rel.icc["ICC(2,k)"] == pytest.approx(0.620051, abs=1e-6)
    assert rel.icc["ICC(3,k)"] == pytest.approx(0.909316, abs=1e-6)
    assert rel.n_targets == 6


def test_icc_pingouin_wine_dataset() -> None:
    import pingouin as pg

    data = pg.read_dataset("icc")
    icc, ci = icc_from_long(data, "Wine", "Judge", "Scores")
    assert icc["ICC(2,k)"] == pytest.approx(0.914450, abs=1e-6)
    assert icc["ICC(3,k)"] == pytest.approx(0.915159, abs=1e-6)
    assert ci["ICC(2,k)"][0] < icc["ICC(2,k)"] < ci["ICC(2,k)"][1]


def test_icc_uses_means_over_repetitions() -> None:
    # Two repetitions that average to the Shrout & Fleiss table give the same ICCs.
    reps = np.stack([SHROUT_FLEISS - 0.5, SHROUT_FLEISS + 0.5], axis=2)
    rel = reliability(_rating_set(reps))
    assert rel.icc["ICC(3,k)"] == pytest.approx(0.909316, abs=1e-6)


def test_inter_rater_matrix_is_pairwise_pearson() -> None:
    rel = reliability(_rating_set(SHROUT_FLEISS[:, :, None]))
    expected = np.corrcoef(SHROUT_FLEISS.T)
    np.testing.assert_allclose(rel.inter_rater.to_numpy(), expected, atol=1e-12)


def test_intra_rater_repetition_correlation() -> None:
    rng = np.random.default_rng(0)
    base = rng.uniform(0, 100, size=(30, 1))
    scores = np.empty((30, 2, 3))
    scores[:, 0, :] = base  # perfectly repeatable rater
    scores[:, 1, :] = base + rng.normal(0, 20, size=(30, 3))
    r = repetition_correlation(scores)
    assert r[0] == pytest.approx(1.0)
    pairs = [(0, 1), (0, 2), (1, 2)]
    expected = np.mean([stats.pearsonr(scores[:, 1, a], scores[:, 1, b])[0] for a, b in pairs])
    assert r[1] == pytest.approx(expected, abs=1e-12)
    single = repetition_correlation(scores[:, :, :1])
    assert np.isnan(single).all()


def test_icc_accepts_the_older_pingouin_names(monkeypatch) -> None:
    """pingouin < 0.7 names the rows ICC2k/ICC3k and the CI column CI95%."""
    import pingouin as pg

    def old_style(**_kwargs):
        return pd.DataFrame({"Type": ["ICC1", "ICC2", "ICC3", "ICC1k", "ICC2k", "ICC3k"],
                             "ICC": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6],
                             "CI95%": [[0.0, 1.0]] * 6})

    monkeypatch.setattr(pg, "intraclass_corr", old_style)
    icc, ci = icc_from_long(pd.DataFrame(), "t", "r", "x")
    assert icc == {"ICC(2,k)": 0.5, "ICC(3,k)": 0.6, "ICC(2,1)": 0.2, "ICC(3,1)": 0.3}
    assert ci["ICC(2,k)"] == (0.0, 1.0)


def test_icc_intervals_are_not_rounded_for_display():
    """pingouin rounds its CI95 column to 2 decimals by default: the report printed them
    with 3, and at high agreement [1.000, 1.000] excluded the estimate. The interval of
    ICC(3,k) from the two-way mean squares (McGraw & Wong 1996, case 3A):
    F = MSR / MSE, [1 - F(0.975; df1, df2) / F, 1 - 1 / (F F(0.975; df2, df1))]."""
    import pingouin

    rng = np.random.default_rng(3)
    n, k = 30, 6
    truth = rng.uniform(0, 100, n)
    scores = truth[:, None] + rng.normal(0, 2.0, (n, k))
    long = pd.DataFrame([(i, j, scores[i, j]) for i in range(n) for j in range(k)],
                        columns=["target", "rater", "rating"])
    icc, ci = icc_from_long(long, "target", "rater", "rating")
    grand = scores.mean()
    msr = k * ((scores.mean(1) - grand) ** 2).sum() / (n - 1)
    resid = scores - scores.mean(1, keepdims=True) - scores.mean(0, keepdims=True) + grand
    mse = (resid ** 2).sum() / ((n - 1) * (k - 1))
    f, df1, df2 = msr / mse, n - 1, (n - 1) * (k - 1)
    low = 1 - stats.f.ppf(0.975, df1, df2) / f
    high = 1 - 1 / (f * stats.f.ppf(0.975, df2, df1))
    assert ci["ICC(3,k)"] == pytest.approx((low, high), abs=1e-9)
    assert ci["ICC(3,k)"][0] < icc["ICC(3,k)"] < ci["ICC(3,k)"][1]
    assert pingouin.options["round.column.CI95"] == 2  # pingouin's own setting is left as is
