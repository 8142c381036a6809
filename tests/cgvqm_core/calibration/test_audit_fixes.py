"""Audit fixes of the calibration: distinct scene splits, --report checks, the weights file's
feature settings and provenance warning, the weights JSON layout."""

from __future__ import annotations

import json
import logging
import math
from itertools import combinations

import numpy as np
import pytest
from scipy import stats

from cgvqm_core.calibration import CalibrationData, FitConfig, validate
from cgvqm_core.calibration import cli as calib_cli
from cgvqm_core.errors import CGVQMError
from cgvqm_core.metric import CGVQM
from cgvqm_core.weights import load_weights, save_weights, uniform_weights

from .calib_synthetic import make
from .test_cli import study  # noqa: F401  (the module fixture: 3 scenes x 4 noise levels)

CFG = FitConfig(steps=50, lr_omega=1e-3, show_progress=False, objective="plcc-signed")


def _fitted_test_rows(res, ratio):
    per = res.per_split
    return per[(per["train_ratio"] == ratio) & (per["model"] == "fitted")
               & (per["subset"] == "test")]


# -- finding 2: distinct splits -------------------------------------------------------------

def test_five_scenes_at_20_80_use_each_of_the_five_splits_once():
    """5 scenes, one trains: there are exactly C(5, 1) = 5 splits; ten seeds must not count
    copies, and the interval is over the five distinct ones."""
    syn = make(n_scenes=5, per_scene=6, n_channels=12, seed=2)
    data = CalibrationData(syn.items, syn.M, syn.counts)
    res = validate(data, [0.2], list(range(10)), CFG, anchor="none")
    rows = _fitted_test_rows(res, 0.2)
    train_scenes = set()
    for _, grp in rows.groupby("split"):
        # the test scenes of a split are the 4 that did not train
        assert grp["n_scenes"].iloc[0] == 4
    assert rows["split"].nunique() == math.comb(5, 1) == 5
    (chosen,) = res.splits
    assert chosen.enumerated and chosen.n_possible == 5
    train_scenes = [s.train_scenes for s in chosen.splits]
    assert sorted(train_scenes) == [(f"synth:scene{i:02d}",) for i in range(5)]
    assert any("all 5 possible" in n for n in res.notes)
    summ = res.summary.query("model == 'fitted' and subset == 'test'").iloc[0]
    assert summ["n_splits"] == 5
    # the interval by hand: t(0.975, 4) * sd / sqrt(5) over the five values
    v = rows["plcc"].to_numpy()
    half = stats.t.ppf(0.975, 4) * v.std(ddof=1) / np.sqrt(5)
    assert summ["plcc"] == pytest.approx(v.mean())
    assert summ["plcc_ci95_low"] == pytest.approx(max(v.mean() - half, -1.0))
    assert summ["plcc_ci95_high"] == pytest.approx(min(v.mean() + half, 1.0))


def test_sampled_splits_are_distinct_and_count_what_was_drawn():
    """8 scenes at 0.25: C(8, 2) = 28 splits, more than 10 asked for: 10 distinct ones."""
    syn = make(n_scenes=8, per_scene=4, n_channels=12, seed=3)
    data = CalibrationData(syn.items, syn.M, syn.counts)
    res = validate(data, [0.25], list(range(10)), CFG, anchor="none")
    (chosen,) = res.splits
    assert not chosen.enumerated and chosen.n_possible == math.comb(8, 2)
    ids = {tuple(sorted(s.train_scenes)) for s in chosen.splits}
    assert len(ids) == len(chosen.splits) == 10
    assert res.summary["n_splits"].eq(10).all()
    seeds = [s.seed for s in chosen.splits]
    assert len(set(seeds)) == 10 and set(chosen.skipped_seeds).isdisjoint(seeds)


def test_enumeration_with_validation_scenes_covers_every_assignment():
    """3 scenes, 2 train of which 1 validates: 3 * 2 = 6 distinct (train, val, test)."""
    from cgvqm_core.calibration.splits import all_splits, count_splits

    scenes = ["a", "b", "c"]
    assert count_splits(scenes, ["d"] * 3, 0.67, val_ratio=0.25) == 6
    got = {(s.train_scenes, s.val_scenes, s.test_scenes)
           for s in all_splits(scenes, ["d"] * 3, 0.67, val_ratio=0.25)}
    want = {((f"d:{t}",), (f"d:{v}",), (f"d:{x}",))
            for t, v in combinations(scenes, 2) for x in scenes if x not in (t, v)}
    want |= {((f"d:{v}",), (f"d:{t}",), (f"d:{x}",))
             for t, v in combinations(scenes, 2) for x in scenes if x not in (t, v)}
    assert got == want and len(got) == 6


# -- finding 8: --report checked before the fit ----------------------------------------------

def _calib_args(study, tmp_path, *extra):  # noqa: F811
    return ["calibrate", "--dataset", f"tiny={study / 'manifest.json'}:{study / 'dmos.csv'}",
            "--random-backbone", "0", "--cache", str(tmp_path / "cache"),
            "--steps", "20", "--lr-omega", "1e-4", "--train-ratio", "0.67",
            "--repeats", "2", "--quiet", *extra]


@pytest.mark.parametrize("which", ["missing-folder", "folder", "out", "dmos", "manifest"])
def test_report_path_refused_before_any_work(study, tmp_path, capsys, which,  # noqa: F811
                                             monkeypatch):
    out = tmp_path / "w.json"
    report = {"missing-folder": tmp_path / "nope" / "r.csv", "folder": tmp_path, "out": out,
              "dmos": study / "dmos.csv", "manifest": study / "manifest.json"}[which]
    before = (study / "dmos.csv").read_bytes()

    def no_data(*a, **k):
        raise AssertionError("the studies were read before --report was checked")

    monkeypatch.setattr("cgvqm_core.calibration.data.load_datasets", no_data)
    rc = calib_cli.main(_calib_args(study, tmp_path, "--out", str(out), "--report",
                                    str(report)))
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "--report" in err, err
    assert not out.exists() and (study / "dmos.csv").read_bytes() == before


def test_report_whose_summary_is_a_dataset_file_is_refused(tmp_path):
    """--report d.csv also writes d.summary.csv: that one must not be an input either."""
    dmos = tmp_path / "d.summary.csv"
    dmos.write_text("stimulus,dmos\n")
    with pytest.raises(CGVQMError, match="its summary"):
        calib_cli._check_report(tmp_path / "d.csv", tmp_path / "w.json",
                                [f"x={tmp_path / 'm.json'}:{dmos}"])


# -- finding 1: feature settings of a calibrated weights file --------------------------------

@pytest.fixture(scope="module")
def calibrated(study, tmp_path_factory):  # noqa: F811
    """A real calibration on random backbone 0 at patch scale 4."""
    tmp = tmp_path_factory.mktemp("calib")
    args = [a for a in _calib_args(study, tmp, "--out", str(tmp / "w.json"), "--no-validation")
            if a not in ("--train-ratio", "0.67", "--repeats", "2")]
    assert calib_cli.main(args) == 0
    return tmp / "w.json"


@pytest.mark.parametrize(("kw", "said"), [
    ({"random_backbone": 0, "patch_scale": 2}, "patch scale 4"),
    ({"random_backbone": 1}, "backbone sha256"),
    ({"random_backbone": 0, "seamless": True}, "mode upstream"),
])
def test_weights_refused_under_other_feature_settings(calibrated, kw, said):
    with pytest.raises(CGVQMError) as exc:
        CGVQM(weights=str(calibrated), **kw)
    msg = str(exc.value)
    assert "\n" not in msg and said in msg and "calibrate again" in msg


def test_weights_used_with_their_settings_show_the_files_warning(calibrated, caplog):
    with caplog.at_level(logging.WARNING, logger="cgvqm_core"):
        metric = CGVQM(weights=str(calibrated), random_backbone=0)
    fitted = metric.weights.provenance["feature_settings"]
    assert fitted["backbone_sha256"] == metric.backbone.sha256 and fitted["patch_scale"] == 4
    assert any("RANDOM backbone" in r.getMessage() and "not a usable metric" in r.getMessage()
               for r in caplog.records)


def test_cli_score_refuses_the_mismatch_in_one_line(calibrated, study, capsys):  # noqa: F811
    from cgvqm_core.cli import main

    ref, test = study / "videos" / "ref0.mkv", study / "videos" / "SRC01_HRC01.mkv"
    rc = main(["score", "--ref", str(ref), "--test", str(test), "--weights", str(calibrated),
               "--random-backbone", "0", "--patch-scale", "2"])
    err = capsys.readouterr().err
    assert rc == 2 and "patch scale 4" in err and err.count("cgvqm: error") == 1, err


def test_weights_without_feature_settings_still_load(tmp_path):
    """Hand-made (or published) weights carry no feature settings: nothing to compare."""
    w = uniform_weights("cgvqm-2")
    w.provenance = {"note": "hand-made"}
    path = save_weights(tmp_path / "hand.json", w)
    metric = CGVQM(weights=str(path), random_backbone=0, patch_scale=2)
    assert metric.weights.kind == "project"


# -- finding 9: the weights JSON layout ------------------------------------------------------

def test_top_level_anchoring_is_refused_not_ignored(tmp_path):
    w = uniform_weights("cgvqm-2")
    path = save_weights(tmp_path / "w.json", w)
    doc = json.loads(path.read_text())
    doc["anchoring"] = {"format": "cgvqm-anchor/1", "kind": "logistic", "pool": "max",
                        "lo": 0, "hi": 100, "center": 50, "scale": 10}
    path.write_text(json.dumps(doc))
    with pytest.raises(CGVQMError, match=r"provenance\.anchoring"):
        load_weights(path)
    # the same anchoring under provenance is read
    doc["provenance"] = {"anchoring": doc.pop("anchoring")}
    path.write_text(json.dumps(doc))
    assert load_weights(path).provenance["anchoring"]["kind"] == "logistic"
