"""From cached features to a weights file the metric loads; provenance; sign handling."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cgvqm_core.calibration import CalibrationData, FitConfig, apply_anchor, pooled_errors
from cgvqm_core.calibration.pipeline import calibrate
from cgvqm_core.calibration.stats import correlations
from cgvqm_core.weights import load_weights, resolve_weights

from .calib_synthetic import make

CFG = FitConfig(steps=600, lr_omega=1e-3, show_progress=False, objective="plcc-signed")
UPSTREAM = FitConfig(steps=600, lr_omega=1e-3, show_progress=False)


@pytest.fixture(scope="module")
def synth131():
    return make(n_scenes=10, per_scene=8, n_channels=131, seed=4)


def test_weights_file_round_trips_with_provenance(tmp_path, synth131):
    data = CalibrationData(synth131.items, synth131.M, synth131.counts)
    out = tmp_path / "w.json"
    res = calibrate(data, "cgvqm-2", CFG, train_ratios=[0.5], repeats=3, seed=7,
                    feature_settings={"variant": "cgvqm-2", "backbone_sha256": "f" * 64},
                    backbone={"sha256": "f" * 64, "label": "test", "random_seed": None},
                    out=out)
    w = load_weights(out)
    assert w.kind == "project" and w.variant == "cgvqm-2"
    np.testing.assert_array_equal(w.omega, res.weights.omega.astype(np.float32))
    assert w.alpha == pytest.approx(res.weights.alpha)
    assert resolve_weights(str(out)).omega.shape == (131,)
    p = w.provenance
    assert p["validation"]["split_seeds"] == [7, 8, 9]
    assert p["optimiser"]["steps"] == 600
    assert p["backbone"]["sha256"] == "f" * 64
    test_rows = [r for r in p["validation"]["summary"]
                 if r["subset"] == "test" and r["model"] == "fitted"]
    assert test_rows and -1 <= test_rows[0]["plcc"] <= 1
    assert any("never used" in n for n in p["validation"]["notes"])
    # the stored anchoring reproduces the pipeline's anchored scores from omega/alpha alone
    q = 100 - w.alpha * pooled_errors(synth131.M, synth131.counts, w.omega)
    anchored = apply_anchor(p["anchoring"], q)
    rmse = np.sqrt(np.mean((anchored - data.y) ** 2))
    assert rmse == pytest.approx(
        p["final_fit"]["correlations_on_fitted_videos"]["synth"]["rmse_anchored"], rel=1e-4)
    def no_nan(token):
        raise AssertionError(f"non-standard JSON constant {token}")

    json.loads(out.read_text(), parse_constant=no_nan)  # strict JSON, nothing executable


def test_anchored_scores_follow_quality_and_a_flipped_target_is_flagged(synth131):
    """|PLCC| fits either direction; the anchoring and the report must not be fooled."""
    data = CalibrationData(synth131.items, synth131.M, synth131.counts)
    good = calibrate(data, "cgvqm-2", CFG, train_ratios=[0.5], repeats=2)
    assert not any("NEGATIVELY" in n for n in good.validation.notes)
    q = 100 - good.weights.alpha * pooled_errors(synth131.M, synth131.counts,
                                                 good.weights.omega)
    anchored = apply_anchor(good.weights.provenance["anchoring"], q)
    c = correlations(anchored, synth131.quality)
    assert c["plcc"] > 0.9
    assert np.sqrt(np.mean((anchored - synth131.quality) ** 2)) < 10
    # a DMOS on an impairment scale read as quality: the target points the other way
    flipped = synth131.items.copy()
    flipped["target"] = 100 - flipped["target"]
    bad = calibrate(CalibrationData(flipped, synth131.M, synth131.counts), "cgvqm-2",
                    UPSTREAM, train_ratios=[0.5], repeats=2)
    assert any("NEGATIVELY" in n for n in bad.validation.notes)
    test = bad.validation.summary.query("model == 'fitted' and subset == 'test'")
    assert (test["plcc"] < 0).all()


def test_validation_reports_train_and_test_with_intervals(synth131):
    data = CalibrationData(synth131.items, synth131.M, synth131.counts)
    res = calibrate(data, "cgvqm-2", CFG, train_ratios=[0.2, 0.5], repeats=3)
    s = res.validation.summary
    assert set(s["train_ratio"]) == {0.2, 0.5}
    fitted = s[s["model"] == "fitted"]
    assert set(fitted["subset"]) == {"train", "test"}
    for _, r in fitted.iterrows():
        assert r["plcc_ci95_low"] <= r["plcc"] <= r["plcc_ci95_high"]
        assert r["n_splits"] == 3
    per = res.validation.per_split
    # every split's test scenes are disjoint from its train scenes (checked on the table)
    assert (per.groupby(["train_ratio", "seed", "model"]).size() > 0).all()
    tr = fitted.set_index(["train_ratio", "subset"])["plcc"]
    assert tr[(0.5, "train")] >= tr[(0.5, "test")] - 0.05  # training is the optimistic side


def test_the_signed_objective_never_fits_the_wrong_direction(synth131):
    """Upstream's 1 - |PLCC| follows whichever sign the random start has (on these data some
    seeds end anti-correlated); 1 - PLCC(q, y) only rewards the right direction."""
    data = CalibrationData(synth131.items, synth131.M, synth131.counts)
    res = calibrate(data, "cgvqm-2", CFG, train_ratios=[0.5], repeats=6)
    train = res.validation.per_split.query("model == 'fitted' and subset == 'train'")
    assert (train["plcc"] > 0.9).all()
    assert not any("NEGATIVELY" in n for n in res.validation.notes)


def test_selection_by_validation_scenes_holds_them_out_of_the_final_fit(synth131):
    data = CalibrationData(synth131.items, synth131.M, synth131.counts)
    cfg = FitConfig(steps=300, lr_omega=1e-3, show_progress=False, objective="plcc-signed",
                    select="val")
    res = calibrate(data, "cgvqm-2", cfg, train_ratios=[0.5], repeats=2, val_ratio=0.4)
    prov = res.weights.provenance
    assert "validation scenes" in prov["selection"]
    n_val = prov["final_fit"]["validation_videos"]
    assert 0 < n_val < len(synth131.items)
    assert prov["final_fit"]["videos"] + n_val == len(synth131.items)
    per = res.validation.per_split
    assert set(per.query("model == 'fitted'")["subset"]) == {"train", "val", "test"}


def test_a_falling_fit_names_the_other_scale_and_is_flagged_without_validation(synth131):
    """A DMOS on the quality scale read as impairment: the warning told the user to add
    the --dmos-scale impairment they had given, and without validation nothing warned."""
    flipped = synth131.items.copy()
    flipped["target"] = 100 - flipped["target"]
    data = CalibrationData(flipped, synth131.M, synth131.counts)
    said = calibrate(data, "cgvqm-2", UPSTREAM, train_ratios=[0.5], repeats=2,
                     dmos_scale="impairment")
    notes = [n for n in said.validation.notes if "NEGATIVELY" in n]
    assert notes and "--dmos-scale quality" in notes[0]
    assert "rerun with --dmos-scale impairment" not in " ".join(said.validation.notes)
    quiet = calibrate(data, "cgvqm-2", UPSTREAM, validation=False, dmos_scale="impairment")
    assert quiet.validation is None
    assert quiet.train_correlations["synth"]["plcc"] < 0
    assert len(quiet.warnings) == 1 and "--dmos-scale quality" in quiet.warnings[0]
    good = calibrate(CalibrationData(synth131.items, synth131.M, synth131.counts), "cgvqm-2",
                     CFG, validation=False)
    assert good.warnings == []
