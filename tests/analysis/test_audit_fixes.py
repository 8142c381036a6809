"""Fixes of the statistics audit (2026): each test fails on the code the audit read.

Expected values come from scipy, pingouin, numpy by hand or the ground truth of the data the
test generates, never from output captured once.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pingouin as pg
import pytest
from scipy import stats

import analysis.metrics as metrics_module
import analysis.scores as scores_module
from analysis.ceiling import split_half
from analysis.cli import main
from analysis.data import PanelAnswers
from analysis.errors import AnalysisError
from analysis.icc import icc_unbalanced
from analysis.inputs import ratings_from_frame
from analysis.metrics import (
    POOLED,
    MetricScores,
    resamples_vary,
    small_sample_factor,
    stratified_indices,
    validate_metrics,
)
from analysis.panel import drop_failed_vision
from analysis.pipeline import AnalysisConfig, prepare, run_analysis
from analysis.reliability import reliability
from analysis.scores import fit_scores
from analysis.synthetic import SyntheticStudy, synthetic_study
from stimuli_manifests import save_manifest


# -- finding 1: stimuli no kept rater rated ----------------------------------------------------
@pytest.fixture(scope="module")
def lonely() -> tuple[SyntheticStudy, pd.DataFrame, str]:
    """12 raters, P01 random; one condition (the victim) rated by P01 alone."""
    st = synthetic_study(n_scenes=6, methods=("blur", "noise", "alias"), levels=2,
                         n_raters=12, n_outliers=1, noise_sd=6.0, bias_sd=4.0, seed=3)
    r = st.ratings
    victim = sorted(set(r.loc[~r["is_hidden_reference"].astype(bool), "stimulus"]))[0]
    return st, r[(r["stimulus"] != victim) | (r["participant"] == "P01")], victim


def _oracle(rs, st: SyntheticStudy, seed: int = 0) -> MetricScores:
    q = st.quality.reindex(rs.stimuli.index).to_numpy()
    noise = np.random.default_rng(seed).normal(0, 2, len(q))
    return MetricScores(pd.DataFrame({
        "stimulus": rs.stimulus_ids, "reference": rs.stimuli["reference"].to_numpy(),
        "metric": "oracle", "score": q + noise, "direction": "higher-better"}))


def test_screening_drops_and_names_stimuli_only_removed_raters_rated(lonely) -> None:
    st, frame, victim = lonely
    rs = ratings_from_frame(frame, st.manifest)
    config = AnalysisConfig(model="mos", outliers="grubbs", n_boot=200, n_splits=100,
                            ci_draws=10)
    used, outliers, screened = prepare(rs, config.check())
    assert "P01" in outliers.removed_names and victim in used.stimulus_ids
    assert victim not in screened.stimulus_ids
    assert screened.n_stimuli == used.n_stimuli - 1
    said = [p for p in screened.problems if victim in p.message]
    assert len(said) == 1 and "screened out" in said[0].message

    a = run_analysis(rs, config, _oracle(rs, st), progress=False)
    assert victim not in set(a.dmos()["stimulus"]) and np.isfinite(a.dmos()["dmos"]).all()
    assert any(victim in p.message for p in a.problems)
    row = a.metrics.table.iloc[0]
    data = a.metrics.data["oracle"]
    assert row["fit"] == "logistic5" and row["n"] == rs.n_stimuli - 1 - 6  # 6 references
    assert row["srcc"] == pytest.approx(stats.spearmanr(data["dmos"], data["oriented"])[0])
    assert row["krcc"] == pytest.approx(stats.kendalltau(data["dmos"], data["oriented"])[0])
    assert np.isfinite(row[["plcc", "rmse", "plcc_ci95_low", "plcc_ci95_high"]]
                       .to_numpy(float)).all()


def test_the_vision_rule_names_the_stimuli_it_empties(lonely) -> None:
    st, frame, victim = lonely
    rs = ratings_from_frame(frame, st.manifest)
    rs = replace(rs, panel=PanelAnswers(screenings={"P01": {"colour": "failed"},
                                                    "P02": {"colour": "passed"}}))
    out = drop_failed_vision(rs)
    assert "P01" not in out.raters and victim not in out.stimulus_ids
    said = [p for p in out.problems if victim in p.message]
    assert len(said) == 1 and "vision" in said[0].message


def test_the_dmos_command_prints_the_stimuli_the_screening_emptied(lonely, tmp_path: Path,
                                                                  capsys) -> None:
    st, frame, victim = lonely
    m = save_manifest(st.manifest.manifest, tmp_path / "m.json")
    frame.to_csv(tmp_path / "r.csv", index=False)
    assert main(["dmos", "--manifest", str(m), "--ratings", str(tmp_path / "r.csv"),
                 "--model", "mos", "--outliers", "grubbs", "--bootstrap", "50",
                 "--out", str(tmp_path / "d.csv")]) == 0
    err = capsys.readouterr().err
    assert "input problem: screening: 1 stimulus left out" in err and victim in err
    assert victim not in set(pd.read_csv(tmp_path / "d.csv")["stimulus"])


def _dmos_frame(n: int = 40, seed: int = 2, methods: np.ndarray | None = None
                ) -> tuple[pd.DataFrame, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    d0 = rng.uniform(20, 100, n)
    q = d0 + rng.normal(0, 12, n)
    methods = np.array(["a", "b", "c"])[np.arange(n) % 3] if methods is None else methods
    frame = pd.DataFrame({"stimulus": [f"S{i}" for i in range(n)], "reference": "R",
                          "scene": "x", "method": methods, "level": 1, "dmos": d0,
                          "ci95_low": d0 - 3, "ci95_high": d0 + 3,
                          "is_hidden_reference": False})
    return frame, d0, q


def _metric(frame: pd.DataFrame, values: dict[str, np.ndarray]) -> MetricScores:
    return MetricScores(pd.concat([pd.DataFrame({
        "stimulus": frame["stimulus"], "reference": "R", "metric": name, "score": v,
        "direction": "higher-better"}) for name, v in values.items()], ignore_index=True))


def test_a_nan_dmos_row_is_left_out_and_said_not_spread_to_every_statistic() -> None:
    frame, d0, q = _dmos_frame()
    frame.loc[7, ["dmos", "ci95_low", "ci95_high"]] = np.nan
    v = validate_metrics(frame, _metric(frame, {"m": q}), n_boot=200)
    row = v.table.iloc[0]
    ok = np.arange(len(d0)) != 7
    assert row["n"] == ok.sum() and row["fit"] == "logistic5"
    assert row["srcc"] == pytest.approx(stats.spearmanr(d0[ok], q[ok])[0])
    assert row["krcc"] == pytest.approx(stats.kendalltau(d0[ok], q[ok])[0])
    assert np.isfinite(row[["plcc", "rmse", "plcc_ci95_low", "plcc_ci95_high"]]
                       .to_numpy(float)).all()
    said = [p for p in v.problems if "S7" in p.message]
    assert len(said) == 1 and "DMOS" in said[0].message


# -- finding 2: SUREAL failures become the package's error -------------------------------------
def test_a_failing_p910_fit_is_an_analysis_error_with_surals_words(lonely) -> None:
    st, frame, _ = lonely
    rs = ratings_from_frame(frame, st.manifest)
    without = rs.with_raters([k for k, r in enumerate(rs.raters) if r != "P01"])  # a gap
    with pytest.raises(AnalysisError) as info:
        fit_scores(without, "p910", n_boot=20)
    message = str(info.value)
    assert "infs or NaNs" in message and "--model mos" in message and "\n" not in message


@pytest.mark.parametrize("model", ["p910", "mle"])
def test_the_cli_turns_a_sureal_failure_into_one_line_and_exit_2(model: str, tmp_path: Path,
                                                                 capsys, monkeypatch) -> None:
    monkeypatch.setattr(scores_module, "run_sureal",
                        lambda cls, rs: {"error": "singular matrix in SUREAL"})
    st = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=6, repetitions=2,
                         seed=2)
    m = save_manifest(st.manifest.manifest, tmp_path / "m.json")
    st.ratings.to_csv(tmp_path / "r.csv", index=False)
    assert main(["dmos", "--manifest", str(m), "--ratings", str(tmp_path / "r.csv"),
                 "--model", model, "--outliers", "none",
                 "--out", str(tmp_path / "d.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "singular matrix in SUREAL" in err[0] and "--model mos" in err[0]
    assert "Traceback" not in err[0] and not (tmp_path / "d.csv").exists()


def test_a_diverged_p910_fit_is_refused_not_used(monkeypatch) -> None:
    """No error from SUREAL, but NaN scores: checked like the mle branch's."""
    st = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=6, repetitions=2,
                         seed=2)
    rs = ratings_from_frame(st.ratings, st.manifest)
    real = scores_module.run_sureal

    def diverged(cls, work):
        out = real(cls, work)
        return {**out, "quality_scores": np.full(work.n_stimuli, np.nan)}

    monkeypatch.setattr(scores_module, "run_sureal", diverged)
    with pytest.raises(AnalysisError, match="not finite"):
        fit_scores(rs, "p910", n_boot=20)


# -- finding 3: the stratified stimulus bootstrap ----------------------------------------------
def test_strata_too_small_are_pooled_and_counted_as_used() -> None:
    groups = np.array(["a"] * 10 + ["b"] * 8 + ["c"] + ["d"] * 2)
    idx, blocks = stratified_indices(groups, 200, np.random.default_rng(0))
    assert set(blocks) == {"a", "b", POOLED}
    pooled = idx[:, blocks[POOLED]]
    assert set(groups[pooled.ravel()]) == {"c", "d"}  # c and d resampled together
    assert len(np.unique(pooled)) == 3
    assert (groups[idx[:, blocks["a"]]] == "a").all()
    # one stimulus per stratum: no information, no interval (not a zero-width one)
    assert np.isnan(small_sample_factor(5, 5))
    assert not resamples_vary({"x": slice(0, 1), "y": slice(1, 2)})
    assert resamples_vary(blocks)


def test_singleton_methods_do_not_collapse_the_intervals_or_the_paired_test() -> None:
    n = 40
    single, d0, q = _dmos_frame(n, methods=np.array([f"m{i}" for i in range(n)]))
    one, _, _ = _dmos_frame(n, methods=np.array(["all"] * n))
    qb = q + np.random.default_rng(5).normal(0, 1.0, n)
    v = validate_metrics(single, _metric(single, {"A": q, "B": qb}), n_boot=400)
    row = v.table.set_index("metric").loc["A"]
    lo, hi = row["plcc_ci95_low"], row["plcc_ci95_high"]
    assert hi - lo > 0.1
    # every method of one stimulus is one pooled stratum: the same as one method
    same = validate_metrics(one, _metric(one, {"A": q, "B": qb}), n_boot=400)
    ref = same.table.set_index("metric").loc["A"]
    assert (lo, hi) == pytest.approx((ref["plcc_ci95_low"], ref["plcc_ci95_high"]))
    # and close to the Fisher-z interval of Pearson's r of the same data
    r = stats.pearsonr(d0, q)[0]
    z, se = np.arctanh(r), 1 / np.sqrt(n - 3)
    assert lo == pytest.approx(np.tanh(z - 1.96 * se), abs=0.06)
    assert hi == pytest.approx(np.tanh(z + 1.96 * se), abs=0.06)
    c = v.comparisons[(v.comparisons["scope"] == "all") & (v.comparisons["metric_a"] == "A")]
    p = float(c["boot_p"].iloc[0])
    assert 0.0 < p < 1.0 and p == pytest.approx(float(c["williams_p"].iloc[0]), abs=0.25)


# -- finding 4: the ICC bootstrap of an unbalanced table resamples raters ----------------------
def _rater_table(rater_sd: float, seed: int = 1, n_t: int = 30, n_r: int = 5
                 ) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    full = (rng.normal(0, 1, (n_t, 1)) + rater_sd * rng.normal(0, 1, (1, n_r))
            + rng.normal(0, 1, (n_t, n_r)))
    gappy = full.copy()
    gappy[rng.random(full.shape) < 0.05] = np.nan
    return full, gappy


def _pingouin_ci(table: np.ndarray, name: str) -> tuple[float, float]:
    long = pd.DataFrame(table).stack().rename("y").rename_axis(["t", "r"]).reset_index()
    out = pg.intraclass_corr(long, "t", "r", "y").set_index("Type")
    old = {"ICC(A,k)": "ICC2k", "ICC(A,1)": "ICC2"}[name]
    key = name if name in out.index else old
    lo, hi = out.loc[key, "CI95" if "CI95" in out.columns else "CI95%"]
    return float(lo), float(hi)


@pytest.mark.parametrize(("ours", "theirs"), [("ICC(2,k)", "ICC(A,k)"),
                                              ("ICC(2,1)", "ICC(A,1)")])
def test_icc2_interval_equals_pingouins_on_complete_data(ours: str, theirs: str) -> None:
    """Raters drawn at random: the ICC(2,*) interval carries the rater variance, as McGraw &
    Wong's F-based interval does (pingouin rounds it to 2 decimals)."""
    full, _ = _rater_table(rater_sd=1.0, seed=1)
    _, ci = icc_unbalanced(full, n_boot=20, seed=0)
    assert ci[ours] == pytest.approx(_pingouin_ci(full, theirs), abs=0.006)


@pytest.mark.parametrize("seed", [0, 1])
def test_icc2_interval_with_gaps_follows_rater_variation(seed: int) -> None:
    """5% gaps (the REML path), strongly varying rater offsets: the interval stays close to
    pingouin's on the same table without the gaps; a stimuli-only bootstrap was far
    narrower on the low side."""
    full, gappy = _rater_table(rater_sd=2.0, seed=seed)
    _, ci = icc_unbalanced(gappy, n_boot=20, seed=0)
    assert ci["ICC(2,k)"] == pytest.approx(_pingouin_ci(full, "ICC(A,k)"), abs=0.06)


def test_reliability_says_what_its_bootstrap_resampled() -> None:
    st = synthetic_study(n_scenes=5, levels=2, n_raters=8, repetitions=1, noise_sd=6, seed=5,
                         special={"Xpart": "partial:0.55"})
    rel = reliability(ratings_from_frame(st.ratings, st.manifest), n_boot=30)
    assert "F-based" in rel.method and "raters random" in rel.method
    lo, hi = rel.icc_ci["ICC(2,k)"]
    assert lo <= rel.icc["ICC(2,k)"] <= hi


# -- section 6: rmse degrees of freedom in fallback resamples, Spearman-Brown of odd panels ----
def test_resamples_that_fell_back_to_the_line_divide_rmse_by_n_minus_2(monkeypatch) -> None:
    frame, _, q = _dmos_frame()
    real = metrics_module.refit_batch
    seen: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def half_fall_back(mapping, qb, yb, **kw):
        pred, ok = real(mapping, qb, yb, **kw)
        ok = ok.copy()
        ok[::2] = False  # as if every other resample had fallen back to the line
        seen.append((np.asarray(yb), pred, ok))
        return pred, ok

    monkeypatch.setattr(metrics_module, "refit_batch", half_fall_back)
    v = validate_metrics(frame, _metric(frame, {"m": q}), n_boot=50)
    assert v.mappings["m"].kind == "logistic5"
    yb, pred, ok = next(s for s in seen if s[0].shape[0] == 50)
    n = yb.shape[1]
    expected = np.sqrt(((yb - pred) ** 2).sum(axis=1) / (n - np.where(ok, 5, 2)))
    np.testing.assert_allclose(v.boot["m"]["rmse"], expected)


def test_spearman_brown_projects_an_odd_panel_to_all_its_raters() -> None:
    st = synthetic_study(n_scenes=6, levels=2, n_raters=7, repetitions=2, noise_sd=8, seed=4)
    rs = ratings_from_frame(st.ratings, st.manifest)
    summary = split_half(rs, 200, seed=1).summary()
    r = summary["plcc"]["median"]
    k = 7 / 3  # halves of 3 raters, a panel of 7
    assert summary["plcc_spearman_brown"]["median"] == pytest.approx(k * r / (1 + (k - 1) * r))
