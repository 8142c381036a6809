"""The truth a simulated panel is checked against: ratings are clipped to the scale, so the
analysis recovers the mean clipped rating, not the latent quality (pilot audit: against the
latent truth the 95 % DMOS intervals covered 25-92 % of stimuli)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from analysis import AnalysisConfig, load_ratings, run_analysis
from stimuli_manifests import parse_manifest, save_manifest
from study_app.simulate import SimulationOptions, simulate_panel
from study_app.simulate_truth import expected_clipped


@pytest.mark.parametrize("mean, sd", [(50.0, 10.0), (97.0, 14.0), (3.0, 8.0), (120.0, 5.0),
                                      (40.0, 0.0)])
def test_the_expected_clipped_rating_is_the_integral(mean, sd):
    if sd == 0:
        expected = float(np.clip(mean, 0, 100))
    else:
        expected = stats.norm.expect(lambda x: np.clip(x, 0.0, 100.0), loc=mean, scale=sd)
    assert expected_clipped(mean, sd, 0.0, 100.0) == pytest.approx(expected, abs=1e-6)


def test_the_analysis_of_a_simulated_panel_covers_the_recoverable_truth(tmp_path):
    refs = [{"id": f"SRC0{i}", "path": f"s{i}.mkv", "scene": f"scene{i}"} for i in (1, 2, 3)]
    conds = [{"reference": r["id"], "path": f"{r['id']}_{m}{lv}.mkv", "method": m, "level": lv}
             for r in refs for m in ("blur", "noise") for lv in (1, 2, 3)]
    manifest = save_manifest(parse_manifest({
        "format": "cgvq-manifest/1", "study_id": "truth", "references": refs,
        "conditions": conds, "protocol": {"repetitions": 2}}), tmp_path / "manifest.json")
    folder = tmp_path / "sim"
    truth = json.loads(simulate_panel(manifest, folder, SimulationOptions(raters=16, seed=4),
                                      progress=False).read_text())
    rs = load_ratings(manifest, sessions=sorted(folder.glob("*.sqlite")))
    a = run_analysis(rs, AnalysisConfig(outliers="none", n_boot=200, n_splits=10,
                                        ci_draws=2), progress=False)
    d = a.dmos().set_index("stimulus")
    stim = {s["id"]: s for s in truth["stimuli"] if not s["is_hidden_reference"]}
    ids = sorted(stim)
    true_dmos = np.array([stim[i]["true_dmos"] for i in ids])
    lo, hi = d.loc[ids, "ci95_low"].to_numpy(), d.loc[ids, "ci95_high"].to_numpy()
    covered = float(np.mean((lo <= true_dmos) & (true_dmos <= hi)))
    assert covered >= 0.8, covered
    # the reference sits near the top: its ratings are clipped, and its expected rating is
    # below the latent quality, so the latent DMOS is not what the intervals are about
    ref = next(s for s in truth["stimuli"] if s["is_hidden_reference"])
    assert ref["expected_rating"] < ref["true_quality"] - 1
    latent = np.array([stim[i]["true_quality"] - 97.0 + 100.0 for i in ids])
    assert np.mean(d.loc[ids, "dmos"].to_numpy() - latent) > 0.5  # biased against it
    assert abs(np.mean(d.loc[ids, "dmos"].to_numpy() - true_dmos)) < 1.5
    # SUREAL's full MLE identifies only inconsistency^2 + ambiguity^2: an estimate left at the
    # boundary 0 gets no interval, the others keep theirs
    sc = a.scores
    for value, ci in ((sc.rater_inconsistency, sc.rater_inconsistency_ci),
                      (sc.content_ambiguity, sc.content_ambiguity_ci)):
        at_zero = value < 1e-6
        assert np.isnan(ci[at_zero]).all() and np.isfinite(ci[~at_zero]).all()
    assert (sc.rater_inconsistency < 1e-6).any() or (sc.content_ambiguity < 1e-6).any()


def test_a_locally_planned_adaptive_study_is_not_said_to_be_planned_by_a_server(tmp_path):
    """Without a server the app plans the later blocks uniformly, and the sessions record
    it (issued_by "session"); the report used to say "planned by the study server"."""
    from analysis.report import _adaptive_words, allocation_sentence, ratings_per_stimulus

    refs = [{"id": f"SRC0{i}", "path": f"s{i}.mkv", "scene": f"scene{i}"} for i in (1, 2)]
    conds = [{"reference": r["id"], "path": f"{r['id']}_blur{lv}.mkv", "method": "blur",
              "level": lv} for r in refs for lv in (1, 2)]
    manifest = save_manifest(parse_manifest({
        "format": "cgvq-manifest/1", "study_id": "adapt", "references": refs,
        "conditions": conds, "protocol": {"repetitions": 1, "allocation": "adaptive",
                                          "adaptive": {"blocks": 2}}}),
        tmp_path / "manifest.json")
    simulate_panel(manifest, tmp_path / "sim", SimulationOptions(raters=4, seed=1),
                   progress=False)
    rs = load_ratings(manifest, sessions=sorted((tmp_path / "sim").glob("*.sqlite")))
    assert set(rs.rater_info["blocks_planned_by"]) == {"session"}
    a = run_analysis(rs, AnalysisConfig(model="mos", outliers="none", n_boot=20,
                                        n_splits=5, ci_draws=2), progress=False)
    sentence = allocation_sentence(a, ratings_per_stimulus(a))
    assert "planned uniformly by the app (no study server)" in sentence, sentence
    settings = {"blocks": 3, "block_trials": None, "max_per_block": 3,
                "warmup_participants": 4}
    # the server's blocks are uniform until its warm-up is done (the session files cannot
    # tell which were which): the sentence says both
    server = _adaptive_words(settings, {"server"})
    assert "uniformly until 4 sessions had finished block 1, then from the DMOS" in server
    assert "later blocks of 1 trial planned" in _adaptive_words({**settings, "block_trials": 1},
                                                                {"server"})
    assert "or uniformly by an app" in _adaptive_words(settings, set())  # a CSV: unknown
