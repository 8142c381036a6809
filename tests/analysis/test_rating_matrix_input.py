"""Ratings as other labs lay them out. A wide ITU-T P.910 rating matrix (one row per stimulus,
one column per rater, repetitions as ``rater#2``) reads as the tidy table it was made from:
the report's own export goes back in, and so does a matrix from another lab with a MOS
column beside the raters. A design that repeats some stimuli less often makes no rater
partial."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from analysis.errors import AnalysisError
from analysis.exports import write_rating_matrix
from analysis.inputs import load_ratings
from analysis.synthetic import synthetic_study
from stimuli_manifests import save_manifest


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    st = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=5, repetitions=2,
                         seed=4)
    root = tmp_path_factory.mktemp("matrix")
    save_manifest(st.manifest.manifest, root / "manifest.json")
    st.ratings.to_csv(root / "ratings.csv", index=False)
    return root


def _same(a, b) -> None:
    assert list(a.raters) == list(b.raters)
    assert list(a.stimulus_ids) == list(b.stimulus_ids)
    np.testing.assert_array_equal(a.scores, b.scores)


def test_the_reports_own_matrix_reads_back_as_the_tidy_ratings(study):
    tidy = load_ratings(study / "manifest.json", ratings_csv=study / "ratings.csv")
    path = write_rating_matrix(tidy, study / "matrix.csv")
    header = pd.read_csv(path, nrows=0).columns
    assert header[0] == "stimulus" and "P01#2" in header  # the wide layout, repetitions apart
    _same(load_ratings(study / "manifest.json", ratings_csv=path), tidy)


def test_a_labs_matrix_with_gaps_and_a_mos_column(study, tmp_path):
    """Semicolons and decimal commas, a missing cell, a MOS column that is not a rater."""
    tidy = load_ratings(study / "manifest.json", ratings_csv=study / "ratings.csv")
    first = tidy.scores[:, :, 0]
    wide = pd.DataFrame(first, columns=tidy.raters, index=tidy.stimulus_ids)
    wide.iloc[0, 1] = np.nan
    wide.insert(0, "MOS", wide.mean(axis=1))
    text = wide.rename_axis("Stimulus").to_csv(sep=";", decimal=",", na_rep="")
    (tmp_path / "lab.csv").write_text(text, encoding="utf-8")
    read = load_ratings(study / "manifest.json", ratings_csv=tmp_path / "lab.csv")
    assert list(read.raters) == list(tidy.raters)
    expected = first.copy()
    expected[0, 1] = np.nan
    np.testing.assert_allclose(read.scores[:, :, 0], expected)


def test_a_stimulus_column_alone_is_refused_in_one_line(tmp_path):
    (tmp_path / "one.csv").write_text("stimulus,mos\nSRC01,50\n", encoding="utf-8")
    from analysis.csv_inputs import read_csv

    with pytest.raises(AnalysisError, match="one column per rater"):
        read_csv(tmp_path / "one.csv")


def test_fewer_repetitions_by_design_make_no_rater_partial(study, tmp_path):
    """Every rater rated half the stimuli twice and the rest once (the manifest says 2): each
    followed the design, so none is partial (all were 75% before); one who skipped a
    stimulus entirely still is."""
    ratings = pd.read_csv(study / "ratings.csv", dtype={"participant": str})
    stimuli = sorted(ratings["stimulus"].unique())
    once = set(stimuli[::2])
    uneven = ratings[~((ratings["repetition"] == 2) & ratings["stimulus"].isin(once))]
    short = uneven[~((uneven["participant"] == "P05") & (uneven["stimulus"] == stimuli[1]))]
    short.to_csv(tmp_path / "uneven.csv", index=False)
    rs = load_ratings(study / "manifest.json", ratings_csv=tmp_path / "uneven.csv")
    comp = dict(zip(rs.raters, rs.completeness(), strict=True))
    planned = len(stimuli) * 2 - len(once)
    assert all(comp[r] == 1.0 for r in rs.raters if r != "P05")
    assert comp["P05"] == pytest.approx((planned - 2) / planned)
    assert rs.allocation == "unbalanced"
