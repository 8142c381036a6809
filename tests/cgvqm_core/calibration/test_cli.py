"""``cgvqm calibrate`` end to end on tiny generated videos with a seeded random backbone."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from cgvqm_core.calibration import cli as calib_cli
from cgvqm_core.calibration.cache import FeatureCache
from stimuli_manifests import write_video

FPS = 8


def _video(rng: np.random.Generator, frames=8, size=32) -> np.ndarray:
    """A smooth moving pattern (features of smooth content are stable)."""
    t = np.arange(frames)[:, None, None]
    y, x = np.mgrid[0:size, 0:size]
    phase = rng.uniform(0, 6.28, 3)
    chans = [127 + 100 * np.sin(0.2 * x + 0.15 * y + 0.4 * t + p) for p in phase]
    return np.clip(np.stack(chans, -1), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """3 scenes x 4 noisy versions; DMOS falls with the noise level."""
    root = tmp_path_factory.mktemp("study")
    (root / "videos").mkdir()
    rng = np.random.default_rng(0)
    refs, conds, dmos = [], [], []
    for s in range(3):
        ref = _video(rng)
        write_video(root / "videos" / f"ref{s}.mkv", ref, FPS)
        refs.append({"id": f"SRC0{s + 1}", "path": f"ref{s}.mkv", "scene": f"scene{s}"})
        for k, sigma in enumerate((4.0, 10.0, 20.0, 35.0), start=1):
            noisy = np.clip(ref + rng.normal(0, sigma, ref.shape), 0, 255).astype(np.uint8)
            cid = f"SRC0{s + 1}_HRC0{k}"
            write_video(root / "videos" / f"{cid}.mkv", noisy, FPS)
            conds.append({"id": cid, "reference": f"SRC0{s + 1}", "path": f"{cid}.mkv",
                          "method": "noise", "level": 5 - k})
            dmos.append({"stimulus": cid, "reference": f"SRC0{s + 1}", "method": "noise",
                         "level": 5 - k, "dmos": 100 - 2.0 * sigma + rng.normal(0, 2),
                         "model": "synthetic"})
    (root / "manifest.json").write_text(json.dumps(
        {"format": "cgvq-manifest/1", "study_id": "tiny", "root": "videos",
         "references": refs, "conditions": conds}))
    pd.DataFrame(dmos).to_csv(root / "dmos.csv", index=False)
    return root


def _args(study, tmp_path, *extra):
    return ["calibrate", "--dataset", f"tiny={study / 'manifest.json'}:{study / 'dmos.csv'}",
            "--random-backbone", "0", "--cache", str(tmp_path / "cache"),
            "--out", str(tmp_path / "w.json"), "--steps", "300", "--lr-omega", "1e-4",
            "--train-ratio", "0.67", "--repeats", "2", "--quiet", *extra]


def test_calibrate_writes_weights_the_metric_scores_with(study, tmp_path, capsys, monkeypatch):
    assert calib_cli.main(_args(study, tmp_path, "--report", str(tmp_path / "r.csv"))) == 0
    out = capsys.readouterr().out
    assert "test" in out and "never used" in out and "RANDOM" in out + capsys.readouterr().err
    doc = json.loads((tmp_path / "w.json").read_text())
    assert doc["format"] == "cgvqm-weights/1" and len(doc["omega"]) == 131
    assert doc["provenance"]["backbone"]["random_seed"] == 0
    assert "RANDOM" in doc["provenance"]["warning"]
    assert (tmp_path / "r.csv").is_file() and (tmp_path / "r.summary.csv").is_file()
    assert len(list((tmp_path / "cache").rglob("*.npy"))) == 12

    # rerun: everything comes from the cache
    def no_compute(self, key, m):
        raise AssertionError("feature recomputed although cached")

    monkeypatch.setattr(FeatureCache, "save_entry", no_compute)
    no_validation = [a for a in _args(study, tmp_path, "--no-validation")
                     if a not in ("--train-ratio", "0.67", "--repeats", "2")]
    assert calib_cli.main(no_validation) == 0

    # the metric, loading the file, scores q = 100 - alpha * max_p(m_p . |omega|) on the
    # very features the calibration cached
    from cgvqm_core.metric import CGVQM

    metric = CGVQM(weights=tmp_path / "w.json", random_backbone=0)
    res = metric.score(study / "videos" / "ref1.mkv", study / "videos" / "SRC02_HRC03.mkv")
    m = metric.channel_msd(study / "videos" / "ref1.mkv",
                           [study / "videos" / "SRC02_HRC03.mkv"])[0].msd
    omega = np.abs(np.asarray(doc["omega"], dtype=np.float64))
    assert res.q == pytest.approx(100 - doc["alpha"] * (m.astype(np.float64) @ omega).max(),
                                  abs=1e-6)
    # and `cgvqm score --weights W` takes the file
    from cgvqm_core.cli import main as cgvqm_main

    capsys.readouterr()
    assert cgvqm_main(["score", "--ref", str(study / "videos" / "ref1.mkv"),
                       "--test", str(study / "videos" / "SRC02_HRC03.mkv"),
                       "--weights", str(tmp_path / "w.json"), "--random-backbone", "0",
                       "--json"]) == 0
    scored = json.loads(capsys.readouterr().out)
    assert scored["q"] == pytest.approx(res.q, abs=1e-6)
    # the stored anchoring puts q on the study's 0..100 scale (logistic written out here)
    anchor = doc["provenance"]["anchoring"]
    assert anchor["kind"] == "logistic" and anchor["pool"] == "max"
    expected = anchor["lo"] + (anchor["hi"] - anchor["lo"]) / (
        1 + np.exp(-(res.q - anchor["center"]) / anchor["scale"]))
    assert scored["q_anchored"] == pytest.approx(expected, abs=1e-6)
    assert 0 <= scored["q_anchored"] <= 100
    assert res.q_anchored == pytest.approx(expected, abs=1e-6)
    # mean pooling has no study-scale score from a max-pooled calibration, and says so
    assert cgvqm_main(["score", "--ref", str(study / "videos" / "ref1.mkv"),
                       "--test", str(study / "videos" / "SRC02_HRC03.mkv"),
                       "--weights", str(tmp_path / "w.json"), "--random-backbone", "0",
                       "--pool", "mean"]) == 0
    out = capsys.readouterr().out
    assert "calibrated to the study scale" not in out
    assert "no study-scale score: w.json was calibrated for max pooling, this is mean" in out


def test_user_errors_exit_2_with_one_line(study, tmp_path, capsys):
    bad = ["calibrate", "--dataset", "nonsense", "--out", str(tmp_path / "w.json"),
           "--random-backbone", "0"]
    assert calib_cli.main(bad) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "NAME=MANIFEST:DMOS_CSV" in err[0]
    missing = ["calibrate", "--dataset", f"x={study / 'manifest.json'}:{tmp_path / 'no.csv'}",
               "--out", str(tmp_path / "w.json"), "--random-backbone", "0",
               "--cache", str(tmp_path / "c")]
    assert calib_cli.main(missing) == 2
    assert "no such DMOS file" in capsys.readouterr().err


@pytest.mark.parametrize("extra,why", [
    (["--seed", "-1"], "--seed -1: must be 0 or more"),
    (["--lr-omega", "-1"], "--lr-omega -1: must be a finite number, positive"),
    (["--lr-alpha", "nan"], "--lr-alpha nan: must be a finite number, 0 or more"),
    (["--alpha-init", "inf"], "--alpha-init inf: must be a finite number, positive"),
    (["--alpha-init", "0"], "--alpha-init 0: must be a finite number, positive"),
])
def test_fit_settings_out_of_range_are_refused_before_any_work(study, tmp_path, capsys,
                                                               extra, why):
    assert calib_cli.main(_args(study, tmp_path, *extra)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and why in err[0], err
    assert not (tmp_path / "cache").exists() and not (tmp_path / "w.json").exists()


@pytest.mark.parametrize("extra,why", [
    # options this run would not read
    (["--no-validation"], "--train-ratio describes the validation splits, which "
                          "--no-validation skips"),
    (["--lr-alpha", "2"], "--lr-alpha has no effect with --objective plcc"),
    (["--objective", "plcc-signed", "--alpha-init", "5"],
     "--alpha-init has no effect with --objective plcc-signed"),
    (["--val-ratio", "0.5"], "--val-ratio sets the held-out share of --select val"),
    (["--features-only"], "--features-only stops once the feature cache is filled: --steps, "
                          "--lr-omega, --train-ratio, --repeats, --out would do nothing"),
])
def test_options_the_run_would_not_read_are_refused(study, tmp_path, capsys, extra, why):
    assert calib_cli.main(_args(study, tmp_path, *extra)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and why in err[0], err
    assert not (tmp_path / "cache").exists() and not (tmp_path / "w.json").exists()


def test_alpha_options_and_val_ratio_are_taken_where_they_apply(study, tmp_path, capsys):
    assert calib_cli.main(_args(study, tmp_path, "--objective", "nmse", "--alpha-init", "5",
                                "--lr-alpha", "0", "--select", "val", "--val-ratio",
                                "0.5")) == 0
    doc = json.loads((tmp_path / "w.json").read_text())
    prov = doc["provenance"]
    assert prov["optimiser"]["alpha_init"] == 5.0 and prov["optimiser"]["lr_alpha"] == 0.0
    assert prov["final_fit"]["alpha_from_optimiser"] == 5.0  # lr 0: alpha stayed at its start
    assert prov["final_fit"]["validation_videos"] == 8  # 0.5 of 3 scenes: 2 (0.25: 1)


def test_the_weights_file_must_be_a_json_file_in_an_existing_folder(study, tmp_path, capsys):
    (tmp_path / "folder.json").mkdir()
    for out, why in ((tmp_path / "w.txt", "ending in .json"),
                     (tmp_path / "folder.json", "is a folder"),
                     (tmp_path / "no" / "w.json", "does not exist")):
        args = _args(study, tmp_path)
        args[args.index("--out") + 1] = str(out)
        assert calib_cli.main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and why in err[0], err
    assert not list(tmp_path.glob("*.part"))


def test_the_cgvqm_command_has_the_calibrate_subcommand(capsys):
    from cgvqm_core.cli import main as cgvqm_main

    assert cgvqm_main(["calibrate", "--dataset", "x=only.json", "--out", "w.json"]) == 2
    assert "NAME=MANIFEST:DMOS_CSV" in capsys.readouterr().err
