"""Score models and DMOS recover the truth of generated panels."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from analysis.inputs import RatingSet, ratings_from_frame
from analysis.scores import dmos_table, fit_scores
from analysis.synthetic import SyntheticStudy, synthetic_study


@pytest.fixture(scope="module")
def clean():
    """Low noise, clear rater biases, no clipping."""
    st = synthetic_study(n_scenes=6, methods=("blur", "noise"), levels=3, n_raters=12,
                         noise_sd=1.0, bias_sd=4.0, seed=7)
    return st, ratings_from_frame(st.ratings, st.manifest)


def test_mos_dmos_is_p910_formula(clean) -> None:
    st, rs = clean
    res = fit_scores(rs, "mos")
    mos = st.ratings.groupby("stimulus")["rating"].mean()
    table = dmos_table(rs, res).set_index("stimulus")
    for sid, row in table.iterrows():
        expected = mos[sid] - mos[row["reference"]] + 100.0
        assert row["dmos"] == pytest.approx(expected, abs=1e-9)
        assert row["mos"] == pytest.approx(mos[sid], abs=1e-9)
    # t-based CI of the plain mean for one stimulus
    votes = st.ratings.loc[st.ratings["stimulus"] == "SRC01_HRC01", "rating"].to_numpy()
    lo, hi = stats.t.interval(0.95, len(votes) - 1, loc=votes.mean(), scale=stats.sem(votes))
    assert table.loc["SRC01_HRC01", "quality_ci95_low"] == pytest.approx(lo, abs=1e-9)
    assert table.loc["SRC01_HRC01", "quality_ci95_high"] == pytest.approx(hi, abs=1e-9)
    assert (table["n_ratings"] == 36).all()


@pytest.mark.parametrize("model", ["mle", "p910"])
def test_mle_recovers_quality_and_bias(clean, model: str) -> None:
    st, rs = clean
    res = fit_scores(rs, model)
    truth = st.quality[rs.stimulus_ids].to_numpy()
    assert np.abs(res.quality - truth).max() < 1.0
    bias = st.bias[rs.raters].to_numpy()
    assert np.abs(res.rater_bias - bias).max() < 0.5
    assert np.corrcoef(res.rater_bias, bias)[0, 1] > 0.99
    assert (res.rater_inconsistency < 2.5).all()
    lo, hi = res.rater_bias_ci[:, 0], res.rater_bias_ci[:, 1]
    assert (lo <= res.rater_bias).all() and (res.rater_bias <= hi).all()
    if model == "mle":
        assert res.content_ambiguity is not None and len(res.content) == 6


def _one_inconsistent_rater() -> tuple[SyntheticStudy, RatingSet]:
    """Ten consistent raters, then P03's ratings made very noisy (s.d. 20): (study, ratings)."""
    st = synthetic_study(n_scenes=5, levels=3, n_raters=10, noise_sd=2.0, bias_sd=0, seed=2)
    frame = st.ratings.copy()
    rng = np.random.default_rng(0)
    sel = frame["participant"] == "P03"
    frame.loc[sel, "rating"] = np.clip(frame.loc[sel, "rating"] + rng.normal(0, 20, sel.sum()),
                                       0, 100)
    rs = ratings_from_frame(frame, st.manifest)
    return st, rs


def test_p910_downweights_an_inconsistent_rater() -> None:
    st, rs = _one_inconsistent_rater()
    res = fit_scores(rs, "p910")
    inc = dict(zip(res.raters, res.rater_inconsistency, strict=True))
    assert inc["P03"] == max(inc.values()) and inc["P03"] > 10
    truth = st.quality[rs.stimulus_ids].to_numpy()
    mos = fit_scores(rs, "mos").quality
    assert np.abs(res.quality - truth).mean() < np.abs(mos - truth).mean()


def test_dmos_order_follows_levels(study) -> None:
    rs = ratings_from_frame(study.ratings, study.manifest)
    from analysis.screening import screen_raters

    kept = rs.with_raters(screen_raters(rs).kept)
    table = dmos_table(kept, fit_scores(kept, "mle"))
    cond = table[~table["is_hidden_reference"]]
    true_dmos = np.array([study.quality[s] - study.quality[r] + 100
                          for s, r in zip(cond["stimulus"], cond["reference"], strict=True)])
    assert stats.spearmanr(cond["dmos"], true_dmos)[0] > 0.95
    # mean DMOS per (method, level): milder levels (higher number) score higher
    by = cond.groupby(["method", "level"])["dmos"].mean()
    for method in cond["method"].unique():
        assert by[method].is_monotonic_increasing
    refs = table[table["is_hidden_reference"]]
    assert np.allclose(refs["dmos"], 100.0)


def test_a_missing_hidden_reference_leaves_its_stimuli_without_dmos(clean) -> None:
    """Their MOS used to stand in the dmos column beside real DMOS (on this 0..100 scale
    about 100 - Q(ref) points off the rest); now they have none, and say why. A design
    without any rated hidden reference keeps quality scores in the column, and says so."""
    st, _ = clean
    frame = st.ratings[st.ratings["stimulus"] != "SRC02"]
    rs = ratings_from_frame(frame, st.manifest)
    res = fit_scores(rs, "mos")
    table = dmos_table(rs, res).set_index("stimulus")
    src02 = table[table["reference"] == "SRC02"]
    assert len(src02) > 0 and src02["dmos"].isna().all() and src02["mos"].notna().all()
    assert src02["ci95_low"].isna().all()
    others = table[(table["reference"] != "SRC02") & ~table["is_hidden_reference"]]
    ref_mos = table.loc[others["reference"], "mos"].to_numpy()
    assert np.allclose(others["dmos"], others["mos"] - ref_mos + 100)  # MOS model: plain
    assert any("SRC02: their stimuli have no DMOS" in p.message for p in res.problems)
    no_refs = st.ratings[~st.ratings["stimulus"].str.fullmatch(r"SRC\d+")]
    rs = ratings_from_frame(no_refs, st.manifest)
    res = fit_scores(rs, "mos")
    table = dmos_table(rs, res)
    assert np.allclose(table["dmos"], table["mos"])
    assert any("for any stimulus: the dmos column holds quality scores" in p.message
               for p in res.problems)


def test_diverging_mle_falls_back_to_p910() -> None:
    """One very noisy rater makes SUREAL's full MLE diverge; the fallback is reported."""
    st, rs = _one_inconsistent_rater()
    res = fit_scores(rs, "mle")
    assert res.model == "p910"
    assert any("fell back" in p.message for p in res.problems)
    assert np.isfinite(res.quality).all()
    assert np.abs(res.quality - st.quality[rs.stimulus_ids].to_numpy()).max() < 3.0


@pytest.mark.parametrize("model", ["mos", "mle"])
def test_a_dmos_behind_fewer_than_three_raters_has_no_interval(clean, model: str) -> None:
    """Two raters' bootstrap has three outcomes and a t quantile of 12.7: its 'interval'
    left the scale, or had zero width where they agreed. Such a DMOS gets none; three raters
    do, and the hidden references keep their exact zero width."""
    st, _ = clean
    r = st.ratings
    raters = sorted(r["participant"].unique())
    two = (r["stimulus"] == "SRC01_HRC01") & ~r["participant"].isin(raters[:2])
    three = (r["stimulus"] == "SRC02_HRC02") & ~r["participant"].isin(raters[:3])
    rs = ratings_from_frame(r[~two & ~three], st.manifest)
    table = dmos_table(rs, fit_scores(rs, model, n_boot=200)).set_index("stimulus")
    assert np.isfinite(table.loc["SRC01_HRC01", "dmos"])
    assert table.loc["SRC01_HRC01", ["ci95_low", "ci95_high"]].isna().all()
    row = table.loc["SRC02_HRC02"]
    assert row["ci95_low"] < row["dmos"] < row["ci95_high"]
    others = table[~table.index.isin(["SRC01_HRC01"]) & ~table["is_hidden_reference"]]
    assert others["ci95_low"].notna().all() and others["ci95_high"].notna().all()
    hidden = table[table["is_hidden_reference"]]
    assert (hidden["ci95_low"] == hidden["dmos"]).all()
