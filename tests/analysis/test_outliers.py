"""Grubbs' test against textbook values; outlier raters found in generated panels."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.cli import main
from analysis.errors import AnalysisError
from analysis.inputs import ratings_from_frame
from analysis.screening import screen_raters
from analysis.screening.grubbs import grubbs_critical, grubbs_statistic
from analysis.synthetic import synthetic_study
from stimuli_manifests import save_manifest


@pytest.mark.parametrize(("n", "table"), [(3, 1.155), (4, 1.481), (5, 1.715), (7, 2.020),
                                          (10, 2.290), (20, 2.709), (30, 2.908)])
def test_grubbs_critical_values_table(n: int, table: float) -> None:
    """Two-sided alpha 0.05 (upper 2.5%) critical values of the published Grubbs tables."""
    assert grubbs_critical(n, 0.05) == pytest.approx(table, abs=1.5e-3)


def test_grubbs_textbook_nitrite_example() -> None:
    """Miller & Miller's nitrite example: 0.380 is suspect among 0.403, 0.410, 0.401.

    G = 1.43 < 1.481 (n = 4); with three more values G = 2.016 < 2.02 (n = 7): kept both times.
    """
    g, k = grubbs_statistic(np.array([0.403, 0.410, 0.401, 0.380]))
    assert k == 3
    assert g == pytest.approx(1.43, abs=5e-3)
    assert g < grubbs_critical(4)
    g7, k7 = grubbs_statistic(np.array([0.403, 0.410, 0.401, 0.380, 0.400, 0.413, 0.411]))
    assert k7 == 3
    assert g7 == pytest.approx(2.016, abs=5e-3)
    assert g7 < grubbs_critical(7) == pytest.approx(2.02, abs=1e-2)


def test_injected_outlier_rater_is_found(study) -> None:
    rs = ratings_from_frame(study.ratings, study.manifest)
    result = screen_raters(rs, "grubbs")
    assert result.removed_names == study.outliers == ["P01"]
    r = result.removed[0]
    assert r.statistic > r.critical
    assert r.critical == pytest.approx(grubbs_critical(20), abs=1e-12)
    assert "P01" not in [rs.raters[k] for k in result.kept]


def test_clean_panel_keeps_everyone() -> None:
    st = synthetic_study(n_scenes=6, levels=2, n_raters=12, noise_sd=6, bias_sd=3, seed=11)
    rs = ratings_from_frame(st.ratings, st.manifest)
    assert screen_raters(rs, "grubbs").removed == []
    assert screen_raters(rs, "none").kept == list(range(12))


@pytest.mark.parametrize("method", ["none", "grubbs", "p913"])
def test_a_single_rater_is_not_told_to_use_outliers_none(method, tmp_path, capsys) -> None:
    """One rater: no screening rule can help, so the message says what is missing (more
    raters) and never advises '--outliers none' (which may be what was given)."""
    st = synthetic_study(n_scenes=3, levels=2, n_raters=4, noise_sd=4, seed=2)
    one = st.ratings[st.ratings["participant"] == "P02"]
    with pytest.raises(AnalysisError, match=r"only 1 rater \(P02\) in the ratings") as err:
        screen_raters(ratings_from_frame(one, st.manifest), method)
    assert "--outliers" not in str(err.value) and "at least 2 raters" in str(err.value)
    ratings = tmp_path / "one.csv"
    one.to_csv(ratings, index=False)
    manifest = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    out = tmp_path / "d.csv"
    assert main(["dmos", "--manifest", str(manifest), "--ratings", str(ratings), "--outliers",
                 method, "--bootstrap", "10", "--splits", "10", "--out", str(out)]) == 2
    err_lines = capsys.readouterr().err.strip().splitlines()
    assert len(err_lines) == 1 and "only 1 rater (P02)" in err_lines[0], err_lines
    assert "use --outliers none" not in err_lines[0] and not out.exists()


def test_two_random_raters_are_both_removed() -> None:
    st = synthetic_study(n_scenes=8, levels=2, n_raters=16, n_outliers=2, noise_sd=5,
                         bias_sd=3, seed=5)
    rs = ratings_from_frame(st.ratings, st.manifest)
    assert sorted(screen_raters(rs, "grubbs").removed_names) == ["P01", "P02"]


def test_bt500_screening(study) -> None:
    """BT.500 rejects a rater whose deviant votes fall on both sides of the panel, and keeps
    one whose deviant votes are one-sided (|P-Q|/(P+Q) >= 0.3), as the recommendation says."""
    import numpy as np

    # As generated, P01 answers uniformly at random: mostly below the (high) panel mean.
    one_sided = screen_raters(ratings_from_frame(study.ratings, study.manifest), "bt500")
    assert "P01" not in one_sided.removed_names and one_sided.deviation["P01"] > 0.05
    frame = study.ratings.copy()
    sel = frame["participant"] == "P01"
    truth = frame.loc[sel, "stimulus"].map(study.quality).to_numpy()
    rng = np.random.default_rng(1)
    frame.loc[sel, "rating"] = np.clip(truth + rng.normal(0, 25, sel.sum()), 0, 100)
    result = screen_raters(ratings_from_frame(frame, study.manifest), "bt500")
    assert result.removed_names == ["P01"]
    assert result.removed[0].statistic > 0.05 and result.removed[0].second < 0.3


@pytest.mark.parametrize("method, names, criticals", [
    ("p913", ("r1", "inconsistency_z"), (0.75, 3.5)),
    ("bt500", ("outside_share", "one_sidedness"), (0.05, 0.3)),
    ("grubbs", ("grubbs_g", "deviation"), (None, None)),
])
def test_a_removal_names_both_statistics_with_their_thresholds(method, names, criticals,
                                                               study):
    """Each rule's two numbers are named (they used to share anonymous 'statistic' and
    'value' columns that meant other things per rule) and agree with its per-rater table."""
    st = study if method == "bt500" else synthetic_study(
        n_scenes=8, levels=2, n_raters=16, n_outliers=2, noise_sd=5, bias_sd=3, seed=5)
    rs = ratings_from_frame(st.ratings, st.manifest)
    if method == "bt500":  # deviant votes on both sides of the panel, as in the test above
        frame = st.ratings.copy()
        sel = frame["participant"] == "P01"
        truth = frame.loc[sel, "stimulus"].map(st.quality).to_numpy()
        frame.loc[sel, "rating"] = np.clip(
            truth + np.random.default_rng(1).normal(0, 25, sel.sum()), 0, 100)
        rs = ratings_from_frame(frame, st.manifest)
    result = screen_raters(rs, method)
    assert result.removed
    table = result.table
    for r in result.removed:
        assert (r.statistic_name, r.second_name) == names
        if method == "grubbs":
            assert r.statistic > r.critical
            assert r.critical in [pytest.approx(grubbs_critical(n, 0.05)) for n in (15, 16)]
            assert np.isnan(r.second_critical)
            continue
        assert (r.critical, r.second_critical) == criticals
        row = table.loc[r.rater]
        assert r.statistic == pytest.approx(row[names[0]])
        assert r.second == pytest.approx(row[names[1]])
