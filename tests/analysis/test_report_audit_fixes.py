"""What researchers read, as the report audit found it: names drawn as written (a ``$...$``
pair in a scene or metric name stopped the report with a matplotlib traceback), and tick
labels that tell the stimuli apart when method and level do not (a SUREAL dataset)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure

from analysis import AnalysisConfig, ratings_from_frame, run_analysis
from analysis.figures import _stimulus_ticks, draw_all, literal_text
from analysis.metrics import MetricScores
from analysis.synthetic import synthetic_study
from stimuli_manifests import LoadedManifest


@pytest.fixture(scope="module")
def dollar_study():
    st = synthetic_study(n_scenes=3, methods=("blur", "noise"), levels=2, n_raters=6,
                         repetitions=1, seed=5)
    manifest = st.manifest.manifest.model_copy(deep=True)
    manifest.references[0].scene = "Bistro $night_1_2$"  # a mathtext parse error
    manifest.references[1].scene = "$5 vs $10"  # typeset as maths, garbled
    loaded = LoadedManifest(manifest, None, st.manifest.root)
    rs = ratings_from_frame(st.ratings, loaded)
    q = st.quality.reindex(rs.stimuli.index).to_numpy()
    scores = MetricScores(pd.DataFrame({
        "stimulus": rs.stimulus_ids, "reference": rs.stimuli["reference"].to_numpy(),
        "metric": "cost $x_1_2$", "score": q, "direction": "higher-better"}))
    config = AnalysisConfig(model="mos", outliers="none", n_boot=20, n_splits=20, ci_draws=4)
    return run_analysis(rs, config, scores, progress=False)


def test_names_with_dollar_signs_are_drawn_as_written(dollar_study, tmp_path):
    drawn = draw_all(dollar_study, tmp_path / "figures")
    assert "dmos_per_scene" in drawn and all(p.stat().st_size > 0 for p, _ in drawn.values())
    with literal_text():
        fig = Figure()
        text = fig.text(0, 0, "$5 vs $10")
        fig.canvas.draw()
    assert text.get_parse_math() is False


def test_ticks_fall_back_to_stimulus_ids_when_method_and_level_repeat():
    sureal_like = pd.DataFrame({"method": ["distorted"] * 3, "level": [np.nan] * 3,
                                "stimulus": ["A_1", "A_2", "A_3"]})
    assert _stimulus_ticks(sureal_like) == ["A_1", "A_2", "A_3"]
    ours = pd.DataFrame({"method": ["blur", "blur", "noise"], "level": [1, 2, 1],
                         "stimulus": ["S_b1", "S_b2", "S_n1"]})
    assert _stimulus_ticks(ours) == ["blur L1", "blur L2", "noise L1"]  # whole method names


def test_methods_table_describes_the_model_and_screening_that_ran(dollar_study):
    """It always described SUREAL's MLE and the p913/grubbs rules, whatever ran."""
    from analysis.report_html import _CI_ESTIMATOR, _MODEL_TEXT, _SCREENING_TEXT, methods_table
    from analysis.scores import MODEL_NAMES
    from analysis.screening.registry import method_names

    table = methods_table(dollar_study).set_index("what")
    model = table.loc["Score model"]
    assert model["setting"] == "--model mos" and "plain mean" in model["meaning"]
    assert "maximum-likelihood" not in model["meaning"]
    assert "plain means" in table.loc["DMOS 95% CI", "meaning"]
    screening = table.loc["Screening", "meaning"]
    assert "no rater is screened out" in screening and "P.913" not in screening
    assert set(_MODEL_TEXT) == set(_CI_ESTIMATOR) == set(MODEL_NAMES)
    assert set(_SCREENING_TEXT) == set(method_names())
