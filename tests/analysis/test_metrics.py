"""Logistic mapping, correlations with bootstrap CIs, paired significance, breakdowns."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from analysis.errors import AnalysisError
from analysis.metrics import (
    MetricScores,
    fit_mapping,
    load_metric_scores,
    logistic5,
    validate_metrics,
)


def _dmos(n: int = 60, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    methods = np.array(["blur", "noise", "alias"])[np.arange(n) % 3]
    return pd.DataFrame({"stimulus": [f"S{i:03d}" for i in range(n)],
                         "reference": "R", "scene": "x", "method": methods,
                         "level": 1, "dmos": rng.uniform(20, 100, n),
                         "is_hidden_reference": False})


def _scores(dmos: pd.DataFrame, name: str, values: np.ndarray, **extra) -> pd.DataFrame:
    return pd.DataFrame({"stimulus": dmos["stimulus"], "reference": "R", "metric": name,
                         "score": values, **extra})


def test_logistic_recovers_an_exact_curve() -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(0, 1, 80)
    y = logistic5((q - np.median(q)) / q.std(), 60.0, 2.0, 0.1, 3.0, 55.0)
    m = fit_mapping(q, y)
    assert m.kind == "logistic5"
    assert np.max(np.abs(m(q) - y)) < 1e-3 * np.ptp(y)


def test_logistic_handles_lower_is_better() -> None:
    rng = np.random.default_rng(1)
    q = rng.uniform(0, 10, 60)
    y = 100 - 8 * q + rng.normal(0, 2, 60)
    m = fit_mapping(q, y)
    assert np.all(np.diff(m(np.sort(q))) <= 1e-9)  # decreasing mapping
    assert stats.pearsonr(m(q), y)[0] > 0.95


def test_fallback_when_too_few_points() -> None:
    m = fit_mapping(np.array([1.0, 2.0, 3.0, 4.0]), np.array([10.0, 20.0, 30.0, 41.0]))
    assert m.kind == "linear (fallback)"
    assert m(np.array([5.0]))[0] == pytest.approx(np.polyval(np.polyfit([1, 2, 3, 4],
                                                  [10, 20, 30, 41], 1), 5.0))


def test_validation_statistics_and_significance() -> None:
    d = _dmos()
    rng = np.random.default_rng(2)
    good = _scores(d, "good", d["dmos"].to_numpy() + rng.normal(0, 4, len(d)))
    # lower-is-better and noisier; on an untrained backbone
    bad = _scores(d, "bad", -d["dmos"].to_numpy() + rng.normal(0, 25, len(d)),
                  backbone="random-init (seed 0)")
    frame = pd.concat([good, bad], ignore_index=True).assign(_source="s.csv", _row=0)
    v = validate_metrics(d, MetricScores(frame), n_boot=400, seed=0,
                         ceiling={"plcc": {"median": 0.9, "ci95_low": 0.8, "ci95_high": 0.95}})
    t = v.table.set_index("metric")
    assert t.loc["good", "srcc"] == pytest.approx(stats.spearmanr(good["score"], d["dmos"])[0])
    assert t.loc["good", "krcc"] == pytest.approx(stats.kendalltau(good["score"], d["dmos"])[0])
    assert t.loc["bad", "srcc"] < 0 < t.loc["bad", "plcc"]  # sign kept; fit-based PLCC positive
    pred = v.mappings["good"](good["score"].to_numpy())
    assert t.loc["good", "plcc"] == pytest.approx(stats.pearsonr(pred, d["dmos"])[0])
    assert t.loc["good", "rmse"] == pytest.approx(np.sqrt(np.mean((pred - d["dmos"]) ** 2)))
    for key in ("plcc", "srcc", "krcc", "rmse"):
        assert t.loc["good", f"{key}_ci95_low"] <= t.loc["good", key] <= \
            t.loc["good", f"{key}_ci95_high"]
    assert "human ceiling (split-half)" in t.index
    assert v.significance.loc["good", "bad"] < 0.05 and v.better.loc["good", "bad"]
    assert v.significance.loc["bad", "good"] > 0.95
    assert v.untrained == {"bad": "random-init (seed 0)"}
    pm = v.per_method.set_index(["metric", "method"])
    sel = d["method"] == "noise"
    expected = stats.pearsonr(pred[sel], d.loc[sel, "dmos"])[0]
    assert pm.loc[("good", "noise"), "plcc"] == pytest.approx(expected)
    assert pm.loc[("good", "noise"), "n"] == 20


def test_metric_csv_problems_and_pooling(tmp_path: Path) -> None:
    d = _dmos(20)
    f = _scores(d, "cgvqm-2", np.arange(20.0), pooling="max")
    f.loc[3, "score"] = np.nan
    f = pd.concat([f, f.iloc[[5]], pd.DataFrame([{"stimulus": "NOPE", "reference": "R",
                                                   "metric": "cgvqm-2", "score": 1.0,
                                                   "pooling": "max"}])])
    path = tmp_path / "scores.csv"
    f.to_csv(path, index=False)
    ms = load_metric_scores([path])
    assert ms.metrics == ["cgvqm-2 (max)"]
    rows = sorted(p.row for p in ms.problems)
    assert rows == [5, 22]  # NaN score on line 5, duplicate on line 22
    v = validate_metrics(d, ms, n_boot=50)
    assert any("NOPE" in p.message and p.row == 23 for p in v.problems)
    assert v.table.loc[0, "n"] == 19


def test_metric_csv_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("stimulus,value\nS1,3\n")
    with pytest.raises(AnalysisError, match="lacks column"):
        load_metric_scores([bad])
    with pytest.raises(AnalysisError, match="does not exist"):
        load_metric_scores([tmp_path / "none.csv"])
    d = _dmos(10)
    other = pd.DataFrame({"stimulus": ["X1", "X2"], "metric": "m", "score": [1.0, 2.0]}) \
        .assign(_source="x", _row=[2, 3])
    with pytest.raises(AnalysisError, match="no metric could be compared"):
        validate_metrics(d, MetricScores(other), n_boot=10)
