"""Metric scores in (direction, provenance flags), the mapping fitted once and in every
resample, correlations with honest intervals, per-method breakdowns and comparisons."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import optimize, stats

from analysis.errors import AnalysisError
from analysis.mapping import fit_mapping, logistic5, refit_batch
from analysis.metrics import (
    CEILING_ROW,
    MetricScores,
    load_metric_scores,
    stratified_indices,
    validate_metrics,
)


def _dmos(n: int = 60, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    methods = np.array(["blur", "noise", "alias"])[np.arange(n) % 3]
    dmos = rng.uniform(20, 100, n)
    return pd.DataFrame({"stimulus": [f"S{i:03d}" for i in range(n)],
                         "reference": "R", "scene": "x", "method": methods,
                         "level": 1, "dmos": dmos, "ci95_low": dmos - 3, "ci95_high": dmos + 3,
                         "is_hidden_reference": False})


def _scores(dmos: pd.DataFrame, name: str, values: np.ndarray,
            direction: str = "higher-better", **extra) -> pd.DataFrame:
    return pd.DataFrame({"stimulus": dmos["stimulus"], "reference": "R", "metric": name,
                         "score": values, "direction": direction, **extra})


# -- the mapping ---------------------------------------------------------------------------
def test_logistic_recovers_an_exact_curve() -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(0, 1, 80)
    y = logistic5((q - np.median(q)) / q.std(), 60.0, 2.0, 0.1, 3.0, 55.0)
    m = fit_mapping(q, y)
    assert m.kind == "logistic5" and m.n_params == 5
    assert np.max(np.abs(m(q) - y)) < 1e-3 * np.ptp(y)


@pytest.mark.parametrize("seed", range(6))
def test_logistic_fit_is_as_good_as_scipy_curve_fit(seed: int) -> None:
    """Our batched Levenberg-Marquardt against scipy's bounded trust-region fit from the same
    starts: never a worse monotone fit."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(0, 1, 120)
    y = 25 + 60 / (1 + np.exp(-7 * (q - 0.5))) + rng.normal(0, 4, 120)
    m = fit_mapping(q, y)
    z = (q - m.center) / m.scale
    best = np.inf
    for p0b2 in (1.0, 3.0, 0.3):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            p, _ = optimize.curve_fit(logistic5, z, y, bounds=(m.lower, m.upper), maxfev=20000,
                                      p0=[np.ptp(y), p0b2, np.median(z), 0.0, y.mean()])
        best = min(best, float(((logistic5(z, *p) - y) ** 2).sum()))
    assert ((m(q) - y) ** 2).sum() <= best * (1 + 1e-5)


def test_logistic_handles_decreasing_data() -> None:
    rng = np.random.default_rng(1)
    q = rng.uniform(0, 10, 60)
    y = 100 - 8 * q + rng.normal(0, 2, 60)
    m = fit_mapping(q, y)
    assert np.all(np.diff(m(np.sort(q))) <= 1e-9)
    assert stats.pearsonr(m(q), y)[0] > 0.95


def test_fallback_when_too_few_points() -> None:
    m = fit_mapping(np.array([1.0, 2.0, 3.0, 4.0]), np.array([10.0, 20.0, 30.0, 41.0]))
    assert m.kind == "linear (fallback)" and m.n_params == 2
    assert m(np.array([5.0]))[0] == pytest.approx(np.polyval(np.polyfit([1, 2, 3, 4],
                                                  [10, 20, 30, 41], 1), 5.0))


@pytest.mark.parametrize("n", [6, 9])
def test_too_few_stimuli_for_five_parameters_get_a_line(n: int) -> None:
    """Below 2 stimuli per parameter, the logistic follows the noise: its in-sample PLCC
    beats the true curve's, so the table would flatter the metric. A line is fitted."""
    rng = np.random.default_rng(4)
    q = np.linspace(0, 1, n)
    y = 20 + 60 * q + rng.normal(0, 8, n)
    m = fit_mapping(q, y)
    assert m.kind == "linear (fallback)" and m.n_params == 2
    slope, intercept = np.polyfit(q, y, 1)
    np.testing.assert_allclose(m(q), slope * q + intercept, rtol=1e-9)
    q10 = np.linspace(0, 1, 10)
    assert fit_mapping(q10, 20 + 60 * q10 + rng.normal(0, 8, 10)).kind == "logistic5"


def test_batched_refit_matches_fitting_each_resample_alone() -> None:
    """refit_batch (all resamples at once, warm-started) against fit_mapping called on each
    resample: the PLCC the interval is built from agrees to well within its own precision."""
    rng = np.random.default_rng(3)
    q = rng.uniform(0, 1, 90)
    y = 20 + 70 / (1 + np.exp(-6 * (q - 0.4))) + rng.normal(0, 5, 90)
    m = fit_mapping(q, y)
    idx = rng.integers(0, 90, (30, 90))
    pred, kept = refit_batch(m, q[idx], y[idx])
    assert kept.all()
    diff = np.array([stats.pearsonr(fit_mapping(q[i], y[i])(q[i]), y[i])[0]
                     - stats.pearsonr(p, y[i])[0] for i, p in zip(idx, pred, strict=True)])
    assert np.abs(diff).max() < 5e-3 and np.percentile(np.abs(diff), 90) < 1e-3


def test_stratified_indices_keep_method_counts() -> None:
    groups = np.array(["a"] * 5 + ["b"] * 3 + ["a"] * 2)
    idx, blocks = stratified_indices(groups, 50, np.random.default_rng(0))
    assert idx.shape == (50, 10)
    assert (groups[idx[:, blocks["a"]]] == "a").all() and blocks["a"].stop == 7
    assert (groups[idx[:, blocks["b"]]] == "b").all()


# -- reading scores ------------------------------------------------------------------------
def test_direction_column_is_required(tmp_path: Path) -> None:
    path = tmp_path / "old.csv"
    pd.DataFrame({"stimulus": ["S1"], "reference": ["R"], "metric": ["psnr"],
                  "score": [30.0]}).to_csv(path, index=False)
    with pytest.raises(AnalysisError, match="no 'direction' column: add a column") as err:
        load_metric_scores([path])
    assert "\n" not in str(err.value)
    bad = tmp_path / "bad.csv"
    pd.DataFrame({"stimulus": ["S1"], "reference": ["R"], "metric": ["psnr"], "score": [30.0],
                  "direction": ["up"]}).to_csv(bad, index=False)
    with pytest.raises(AnalysisError, match="'up' is not one of higher-better, lower-better"):
        load_metric_scores([bad])
    mixed = tmp_path / "mixed.csv"
    pd.DataFrame({"stimulus": ["S1", "S2"], "reference": "R", "metric": "m", "score": [1, 2.0],
                  "direction": ["higher-better", "lower-better"]}).to_csv(mixed, index=False)
    with pytest.raises(AnalysisError, match="both higher-better and lower-better"):
        load_metric_scores([mixed])


def test_unknown_format_major_version_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "v9.csv"
    pd.DataFrame({"stimulus": ["S1"], "reference": ["R"], "metric": ["psnr"], "score": [3.0],
                  "direction": ["higher-better"], "format": ["cgvq-scores/9"]}) \
        .to_csv(path, index=False)
    with pytest.raises(AnalysisError, match="not supported by this toolkit"):
        load_metric_scores([path])


def test_provenance_flags_survive(tmp_path: Path) -> None:
    d = _dmos(12)
    frames = [
        _scores(d, "cgvqm-2", d["dmos"], backbone="random seed 0"),
        _scores(d, "cgvqm-5-uniform", d["dmos"], weights_sha256="uniform"),
        _scores(d, "cgvqm-x", d["dmos"], settings='{"random_backbone": 3}'),
        _scores(d, "psnr", d["dmos"], backbone="", weights_sha256="ab12"),
    ]
    path = tmp_path / "s.csv"
    pd.concat(frames).to_csv(path, index=False)
    ms = load_metric_scores([path])
    assert set(ms.flags) == {"cgvqm-2", "cgvqm-5-uniform", "cgvqm-x"}
    assert "random" in ms.flags["cgvqm-2"] and "uniform" in ms.flags["cgvqm-5-uniform"]
    v = validate_metrics(d, ms, n_boot=40)
    t = v.table.set_index("metric")
    assert t.loc["cgvqm-2", "flag"] and not t.loc["psnr", "flag"]
    assert v.untrained == ms.flags


def test_metric_csv_problems_and_pooling(tmp_path: Path) -> None:
    d = _dmos(20)
    f = _scores(d, "cgvqm-2", np.arange(20.0), pooling="max")
    f.loc[3, "score"] = np.nan
    f = pd.concat([f, f.iloc[[5]], pd.DataFrame([{"stimulus": "NOPE", "reference": "R",
                                                   "metric": "cgvqm-2", "score": 1.0,
                                                   "pooling": "max",
                                                   "direction": "higher-better"}])])
    path = tmp_path / "scores.csv"
    f.to_csv(path, index=False)
    ms = load_metric_scores([path])
    assert ms.metrics == ["cgvqm-2 (max)"]
    assert sorted(p.row for p in ms.problems) == [5, 22]  # NaN on line 5, duplicate line 22
    v = validate_metrics(d, ms, n_boot=50)
    assert any("NOPE" in p.message and p.row == 23 for p in v.problems)
    assert v.table.loc[0, "n"] == 19


def test_a_metric_that_does_not_apply_is_not_an_input_problem(tmp_path: Path) -> None:
    d = _dmos(20)
    why = "not applicable at 128x128: MS-SSIM needs at least 161x161 pixels"
    na = _scores(d, "ms-ssim", np.nan, note=why)
    broken = _scores(d, "psnr", np.arange(20.0) + 1, note="")
    broken.loc[4, "score"] = np.nan  # empty without a reason: a broken row
    path = tmp_path / "scores.csv"
    pd.concat([na, broken]).to_csv(path, index=False)
    ms = load_metric_scores([path])
    assert ms.metrics == ["psnr"]
    assert [p.row for p in ms.problems] == [26]  # header + 20 ms-ssim rows + 5th psnr row
    assert set(ms.not_applicable) == {"ms-ssim"}
    assert why in ms.not_applicable["ms-ssim"] and "20 stimuli" in ms.not_applicable["ms-ssim"]
    v = validate_metrics(d, ms, n_boot=20)
    assert v.not_applicable == ms.not_applicable
    assert list(v.table["metric"][:1]) == ["psnr"] and v.table.loc[0, "n"] == 19


def test_metric_csv_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("stimulus,value\nS1,3\n")
    with pytest.raises(AnalysisError, match="not a metric scores table"):
        load_metric_scores([bad])
    with pytest.raises(AnalysisError, match="does not exist"):
        load_metric_scores([tmp_path / "none.csv"])
    d = _dmos(10)
    other = pd.DataFrame({"stimulus": ["X1", "X2"], "metric": "m", "score": [1.0, 2.0]}) \
        .assign(_source="x", _row=[2, 3])
    with pytest.raises(AnalysisError, match="no metric could be compared"):
        validate_metrics(d, MetricScores(other), n_boot=10)


@pytest.mark.parametrize(("value", "says"), [("abc", "e.g. 'abc'"), ("nan", "empty or NaN"),
                                             ("", "empty or NaN")])
def test_scores_that_are_not_numbers_are_named_not_called_unshared(value, says,
                                                                    tmp_path: Path) -> None:
    """Stimulus ids that match, but no numeric score: the message names the file, the column
    and the lines (it used to say 'no shared stimuli')."""
    d = _dmos(6)
    path = tmp_path / "scores.csv"
    _scores(d, "psnr", [value] * 6).to_csv(path, index=False)
    with pytest.raises(AnalysisError) as err:
        load_metric_scores([path])
    text = str(err.value)
    assert f"metric scores file {path}: column 'score' is not a finite number" in text
    assert "lines 2-7" in text and says in text and "shared" not in text


@pytest.mark.parametrize("n", [1, 2])
def test_too_few_shared_stimuli_says_how_many(n: int, tmp_path: Path) -> None:
    d = _dmos(10)
    path = tmp_path / "scores.csv"
    _scores(d.head(n), "psnr", np.arange(n, dtype=float)).to_csv(path, index=False)
    with pytest.raises(AnalysisError) as err:
        validate_metrics(d, load_metric_scores([path]), n_boot=10)
    text = str(err.value)
    assert f"psnr: only {n} stimul" in text and "a correlation needs at least 3" in text
    assert "no shared stimuli" not in text


# -- validation ----------------------------------------------------------------------------
def test_validation_statistics_direction_and_significance() -> None:
    d = _dmos()
    rng = np.random.default_rng(2)
    good = _scores(d, "good", d["dmos"].to_numpy() + rng.normal(0, 4, len(d)))
    # lower-is-better and noisier
    bad = _scores(d, "bad", -d["dmos"].to_numpy() + rng.normal(0, 25, len(d)),
                  direction="lower-better")
    v = validate_metrics(d, MetricScores(pd.concat([good, bad], ignore_index=True)),
                         n_boot=400, seed=0,
                         ceiling={"plcc": {"median": 0.9, "p2_5": 0.8, "p97_5": 0.95}})
    t = v.table.set_index("metric")
    y = d["dmos"].to_numpy()
    assert t.loc["good", "srcc"] == pytest.approx(stats.spearmanr(good["score"], y)[0])
    assert t.loc["good", "krcc"] == pytest.approx(stats.kendalltau(good["score"], y)[0])
    # lower-better is oriented: its rank correlations are positive
    assert t.loc["bad", "srcc"] == pytest.approx(-stats.spearmanr(bad["score"], y)[0])
    assert t.loc["bad", "srcc"] > 0 and t.loc["bad", "direction"] == "lower-better"
    pred = v.mappings["good"](good["score"].to_numpy())
    assert t.loc["good", "plcc"] == pytest.approx(stats.pearsonr(pred, y)[0])
    # P.1401 rmse with N - d (d = 5 for the logistic)
    d_good = int(t.loc["good", "d"])
    assert t.loc["good", "rmse"] == pytest.approx(
        np.sqrt(((pred - y) ** 2).sum() / (len(y) - d_good)))
    err = np.maximum(0, np.abs(pred - y) - 3.0)
    assert t.loc["good", "rmse_star"] == pytest.approx(
        np.sqrt((err ** 2).sum() / (len(y) - d_good)))
    assert t.loc["good", "outlier_ratio"] == pytest.approx(np.mean(np.abs(pred - y) > 3.0))
    for key in ("plcc", "srcc", "krcc", "rmse"):
        assert t.loc["good", f"{key}_ci95_low"] <= t.loc["good", key] <= \
            t.loc["good", f"{key}_ci95_high"]
    assert CEILING_ROW in t.index and CEILING_ROW.startswith("two half panels")
    # the splits' percentiles fill the row's interval columns
    assert (t.loc[CEILING_ROW, "plcc_ci95_low"], t.loc[CEILING_ROW, "plcc_ci95_high"]) \
        == (0.8, 0.95)
    assert v.significance.loc["good", "bad"] < 0.05 and v.better.loc["good", "bad"]
    assert v.significance.loc["bad", "good"] > 0.95
    assert v.williams.loc["good", "bad"] < 0.05
    c = v.comparisons
    assert set(c["scope"]) == {"all", "blur", "noise", "alias"}
    row = c[(c["scope"] == "all") & (c["metric_a"] == "good")].iloc[0]
    assert row["williams_p"] < 0.05 and row["steiger_p"] < 0.05 and row["rmse_p"] < 0.05
    pm = v.per_method.set_index(["metric", "method"])
    sel = (d["method"] == "noise").to_numpy()
    assert pm.loc[("good", "noise"), "plcc"] == pytest.approx(
        stats.pearsonr(pred[sel], y[sel])[0])
    assert pm.loc[("good", "noise"), "n"] == 20
    assert pm.loc[("good", "noise"), "plcc_ci95_low"] < pm.loc[("good", "noise"), "plcc"]


def test_intervals_refit_the_mapping_and_are_wider_than_a_fixed_mapping() -> None:
    """The old intervals resampled stimuli with the mapping fitted once on all data; refitting
    in every resample must not give narrower PLCC intervals (the fixed mapping is too kind)."""
    from analysis.stats import pearson_columns

    d = _dmos(40, seed=5)
    rng = np.random.default_rng(5)
    q = d["dmos"].to_numpy() ** 1.3 + rng.normal(0, 25, 40)
    v = validate_metrics(d, MetricScores(_scores(d, "m", q)), n_boot=600, seed=1)
    row = v.table.iloc[0]
    ours = row["plcc_ci95_high"] - row["plcc_ci95_low"]
    fixed = v.mappings["m"](q)
    y = d["dmos"].to_numpy()
    idx = np.random.default_rng(1).integers(0, 40, (600, 40))
    r = pearson_columns(y[idx].T, fixed[idx].T)
    lo, hi = np.percentile(r, [2.5, 97.5])
    assert ours >= (hi - lo) * 0.95


def test_reads_the_layout_cgvqm_batch_writes(tmp_path: Path) -> None:
    """A scores file in the exact column layout of ``cgvqm batch`` (written through the same
    table contract): many metrics, directions, a random-backbone CGVQM with uniform weights,
    a metric that could not score one stimulus (empty score with a note)."""
    batch = pytest.importorskip("cgvqm_core.batch")
    from stimuli_manifests.tables import SCORES, write_table

    d = _dmos(24)
    rng = np.random.default_rng(9)
    rows = []
    for name, direction, extra in (
            ("psnr", "higher-better", {}),
            ("flip", "lower-better", {}),
            ("cgvqm-2-uniform", "higher-better",
             {"backbone": "random seed 0", "weights_sha256": "uniform", "pooling": "mean"})):
        sign = -1.0 if direction == "lower-better" else 1.0
        for k, (sid, y) in enumerate(zip(d["stimulus"], d["dmos"], strict=True)):
            score = "" if (name == "psnr" and k == 0) else f"{sign * y + rng.normal(0, 5):.6g}"
            rows.append({"stimulus": sid, "reference": "R", "metric": name, "score": score,
                         "direction": direction, "note": "too small" if score == "" else "",
                         "key": f"{name}{k}", **extra})
    path = write_table(tmp_path / "scores.csv", SCORES, rows, columns=batch.SCORE_COLUMNS[:-1])
    ms = load_metric_scores([path])
    assert set(ms.metrics) == {"psnr", "flip", "cgvqm-2-uniform (mean)"}
    assert "uniform" in ms.flags["cgvqm-2-uniform (mean)"]
    assert "random" in ms.flags["cgvqm-2-uniform (mean)"]
    assert not ms.problems  # a stated reason makes it "not applicable", not a broken row
    assert ms.not_applicable["psnr"].startswith("too small (1 stimulus")
    v = validate_metrics(d, ms, n_boot=60)
    t = v.table.set_index("metric")
    assert (t.loc[["psnr", "flip"], "srcc"] > 0.5).all()
