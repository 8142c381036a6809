"""The dashboard and the report show the same panel correlation for the same rater."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pandas")

from analysis import AnalysisConfig, ratings_from_frame, run_analysis
from analysis.quality import MIN_PANEL_STIMULI
from analysis.synthetic import synthetic_study
from study_server.analysis_adapter import panel_correlation


def test_dashboard_and_report_agree_for_every_rater():
    st = synthetic_study(n_scenes=3, methods=("blur", "noise"), levels=2, n_raters=8,
                         repetitions=2, seed=5)
    frame = st.ratings.copy()
    # One rater saw only a few stimuli: too few for a panel correlation in either place.
    few = frame["participant"].unique()[0]
    keep = frame["stimulus"].unique()[:MIN_PANEL_STIMULI - 1]
    frame = frame[(frame["participant"] != few) | frame["stimulus"].isin(keep)]

    dashboard = panel_correlation(frame, st.manifest)
    rs = ratings_from_frame(frame, st.manifest, source="test")
    analysis = run_analysis(rs, AnalysisConfig(outliers="none", n_boot=20, n_splits=20,
                                               ci_draws=5), progress=False)
    report = analysis.quality["loo_r"]

    assert few not in dashboard and np.isnan(report[few])
    shown = {str(r): float(v) for r, v in report.items() if np.isfinite(v)}
    assert shown == pytest.approx(dashboard, abs=0, rel=0)
    assert len(shown) == rs.n_raters - 1

    # Independently: Pearson r of each rater's per-stimulus means with the others' mean.
    means = frame.pivot_table(index="stimulus", columns="participant", values="rating",
                              aggfunc="mean")
    for rater, r in dashboard.items():
        others = means.drop(columns=rater).mean(axis=1)
        mine = means[rater]
        ok = mine.notna()
        assert r == pytest.approx(np.corrcoef(mine[ok], others[ok])[0, 1], abs=1e-12)
