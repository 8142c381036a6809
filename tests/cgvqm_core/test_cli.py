"""The ``cgvqm`` command line: score, batch (resumable CSV), weights, and bad inputs."""

from __future__ import annotations

import csv
import json
import pickle
import shutil
from pathlib import Path

import av
import numpy as np
import pytest
import torch

from cgvqm_core import CGVQM
from cgvqm_core.batch import SCORE_COLUMNS
from cgvqm_core.cli import main
from cgvqm_core.weights import FeatureWeights, save_weights
from stimuli_manifests import write_video

FPS = 6


@pytest.fixture
def weights_file(tmp_path) -> Path:
    """An upstream-format pickle of this test's own (not the published) weights."""
    g = torch.Generator().manual_seed(0)
    omega = torch.rand(1, 131, 1, 1, 1, generator=g) / 131
    path = tmp_path / "w2.pickle"
    path.write_bytes(pickle.dumps([omega, torch.tensor(40.0)], protocol=4))
    return path


@pytest.fixture
def pair(tmp_path, vids) -> tuple[Path, Path]:
    ref = vids.smooth(1, 8, 20, 24)
    r = write_video(tmp_path / "ref.mkv", ref, FPS)
    t = write_video(tmp_path / "test.mkv", vids.distort(ref, 2), FPS)
    return r, t


def _run(capsys, *args) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def test_score_json_matches_api(capsys, pair, weights_file, backbone_file, tmp_path):
    ref, test = pair
    rc, out, err = _run(capsys, "score", "--ref", ref, "--test", test, "--weights", weights_file,
                        "--backbone", backbone_file, "--pool", "mean", "--json",
                        "--emap", tmp_path / "em.mkv")
    assert rc == 0, err
    doc = json.loads(out)
    for key in ("q", "variant", "pool", "label", "per_clip", "backbone_sha256", "weights_sha256"):
        assert key in doc
    assert doc["pool"] == "mean" and doc["variant"] == "cgvqm-2" and not doc["random_backbone"]
    api = CGVQM(weights=weights_file, backbone=backbone_file).score(ref, test, pool="mean")
    assert doc["q"] == pytest.approx(api.q, abs=1e-9)
    assert len(doc["per_clip"]) == 2 and len(doc["per_frame"]) == 8
    with av.open(str(tmp_path / "em.mkv")) as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(frames) == 8 and frames[0].shape == (20, 24, 3)


def test_score_names_the_metric_as_its_csv_row_does(capsys, pair, backbone_file, tmp_path):
    """Calibrated weights make another metric: the terminal line and --json name it as the
    CSV row does (the file's stem after the variant), not as plain cgvqm-2."""
    ref, test = pair
    omega = np.linspace(0.5, 2.0, 131, dtype=np.float32) / 131
    calib = save_weights(tmp_path / "calib_w.json",
                         FeatureWeights("cgvqm-2", omega, 40.0, "", "", "project", {}))
    common = ["score", "--ref", ref, "--test", test, "--weights", calib,
              "--backbone", backbone_file]
    rc, out, err = _run(capsys, *common, "--csv", tmp_path / "s.csv")
    assert rc == 0, err
    assert out.startswith("cgvqm-2-calib_w q = "), out
    with (tmp_path / "s.csv").open(newline="") as fh:
        (row,) = list(csv.DictReader(fh))
    assert row["metric"] == "cgvqm-2-calib_w"
    rc, out, err = _run(capsys, *common, "--json")
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["metric"] == "cgvqm-2-calib_w" and doc["variant"] == "cgvqm-2"
    assert doc["q"] == pytest.approx(float(row["score"]), rel=1e-6)


def test_random_backbone_is_marked(capsys, pair, weights_file, tmp_path):
    ref, test = pair
    rc, out, err = _run(capsys, "score", "--ref", ref, "--test", test, "--weights", weights_file,
                        "--random-backbone", "0", "--json", "--csv", tmp_path / "s.csv")
    assert rc == 0
    doc = json.loads(out)
    assert doc["random_backbone"] and doc["backbone"] == "random-seed-0" and "warning" in doc
    assert "RANDOM" in err
    rows = list(csv.DictReader((tmp_path / "s.csv").open()))
    assert rows[0]["backbone"] == "random-seed-0"


def _npy(path: Path, arr: np.ndarray) -> Path:
    np.save(path, arr)
    return path


def test_bad_inputs_exit_2(capsys, pair, weights_file, tmp_path, vids):
    ref, _ = pair
    base = ["--weights", weights_file, "--random-backbone", "0"]
    corrupt = tmp_path / "corrupt.mp4"
    corrupt.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    other_fps = write_video(tmp_path / "fps10.mkv", vids.smooth(1, 8, 20, 24), 10)
    deep = _npy(tmp_path / "deep.npy", np.zeros((8, 20, 24, 3), np.uint16))
    alpha = _npy(tmp_path / "alpha.npy", np.zeros((8, 20, 24, 4), np.uint8))
    empty = _npy(tmp_path / "empty.npy", np.zeros((0, 20, 24, 3), np.uint8))
    bad_w = tmp_path / "cgvqm-2.pickle"
    bad_w.write_bytes(weights_file.read_bytes())  # published name, wrong hash
    cases = [
        (["--test", tmp_path / "missing.mkv"], "no such file"),
        (["--test", corrupt], "corrupt|not a readable|no frames"),
        (["--test", other_fps], "--allow-resample"),
        (["--test", deep], "--allow-convert|allow conversion"),
        (["--test", alpha], "alpha"),
        (["--test", empty], "no frames"),
    ]
    for extra, pattern in cases:
        rc, _, err = _run(capsys, "score", "--ref", ref, *extra, *base)
        assert rc == 2, (extra, err)
        lines = [ln for ln in err.strip().splitlines() if "error" in ln]
        assert len(lines) == 1 and "Traceback" not in err
        assert any(p in lines[0] for p in pattern.split("|")), lines[0]
    rc, _, err = _run(capsys, "score", "--ref", ref, "--test", other_fps, "--weights", bad_w,
                      "--random-backbone", "0", "--allow-resample")
    assert rc == 2 and "does not match" in err
    # allowed explicitly: resampled / converted with a warning
    rc, _, err = _run(capsys, "score", "--ref", ref, "--test", other_fps, "--allow-resample",
                      *base)
    assert rc == 0 and "resampled" in err
    rc, _, err = _run(capsys, "score", "--ref", ref, "--test", deep, "--allow-convert",
                      "--fps", FPS, *base)
    assert rc == 0 and "converted" in err


def _manifest(tmp_path: Path, vids) -> Path:
    root = tmp_path / "videos"
    refs, conds = [], []
    for r in range(2):
        ref = vids.smooth(10 + r, 6, 16, 20)
        write_video(root / f"src{r}.mkv", ref, FPS)
        refs.append({"path": f"src{r}.mkv", "scene": f"scene{r}"})
        for lv in (1, 2):
            write_video(root / f"src{r}_n{lv}.mkv", vids.distort(ref, 100 + r * 10 + lv,
                                                                 sigma=12.0 / lv), FPS)
            conds.append({"reference": f"SRC{r + 1:02d}", "path": f"src{r}_n{lv}.mkv",
                          "method": "noise", "level": lv})
    doc = {"format": "cgvq-manifest/1", "study_id": "t", "root": "videos",
           "references": refs, "conditions": conds}
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(doc))
    return path


def test_batch_resumes_and_appends_variants(capsys, tmp_path, vids, weights_file):
    manifest = _manifest(tmp_path, vids)
    out = tmp_path / "scores.csv"
    args = ["batch", "--manifest", manifest, "--out", out, "--random-backbone", "0",
            "--weights", "uniform"]
    rc, stdout, err = _run(capsys, *args, "--variant", "cgvqm-2")
    assert rc == 0, err
    rows = list(csv.DictReader(out.open()))
    assert tuple(rows[0]) == SCORE_COLUMNS
    assert {r["stimulus"] for r in rows} == {"SRC01_HRC01", "SRC01_HRC02", "SRC02_HRC01",
                                             "SRC02_HRC02"}
    assert all(r["metric"] == "cgvqm-2-uniform" and r["backbone"] == "random-seed-0"
               for r in rows)
    # stronger noise (level 1) scores lower than level 2 for each reference
    q = {r["stimulus"]: float(r["score"]) for r in rows}
    assert q["SRC01_HRC01"] < q["SRC01_HRC02"] and q["SRC02_HRC01"] < q["SRC02_HRC02"]
    # rerun: nothing new; adding mean pooling and hidden references appends only those rows
    rc, stdout, _ = _run(capsys, *args, "--variant", "cgvqm-2")
    assert "0 scored, 4 already" in stdout
    rc, stdout, _ = _run(capsys, *args, "--variant", "cgvqm-2", "--pool", "max", "--pool",
                         "mean", "--include-references")
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 4 + 4 + 2 * 2
    refs = [r for r in rows if r["stimulus"] == "SRC01"]
    assert all(abs(float(r["score"]) - 100) < 1e-6 for r in refs)
    # an interrupted run (simulated: drop the last rows) is completed on rerun
    lines = out.read_text().splitlines()
    out.write_text("\n".join(lines[:-3]) + "\n")
    rc, stdout, _ = _run(capsys, *args, "--variant", "cgvqm-2", "--pool", "max", "--pool",
                         "mean", "--include-references")
    rows2 = list(csv.DictReader(out.open()))
    assert sorted((r["stimulus"], r["pooling"]) for r in rows2) == sorted(
        (r["stimulus"], r["pooling"]) for r in rows)


def test_weights_commands(capsys, weights_file, upstream_dir, backbone_file, tmp_path):
    rc, out, _ = _run(capsys, "weights", "info", weights_file)
    assert rc == 0 and json.loads(out)["n_channels"] == 131
    rc, _, err = _run(capsys, "weights", "verify")
    assert rc == 2 and "weights fetch" in err
    rc, out, err = _run(capsys, "weights", "fetch", "--from", upstream_dir, "--no-backbone")
    assert rc == 0 and out.count("sha256 verified") == 2
    rc, out, err = _run(capsys, "weights", "fetch", "--from", upstream_dir)
    assert rc == 2 and not out  # no backbone in DIR nor cached: refused before any copy
    assert "holds no r3d_18-b3b3357e.pth" in err and "--no-backbone" in err
    own = tmp_path / "own"  # --from DIR takes DIR's backbone (a copy: shared data is read only)
    shutil.copytree(upstream_dir, own)
    beside = own / "r3d_18-b3b3357e.pth"
    beside.write_bytes(Path(backbone_file).read_bytes())
    rc, out, err = _run(capsys, "weights", "fetch", "--from", own)
    assert rc == 2 and f"{beside}: sha256" in err and "does not start with b3b3357e" in err
    rc, out, err = _run(capsys, "weights", "fetch", "--from", upstream_dir, "--backbone-file",
                        backbone_file)
    assert rc == 2 and "is not the one of r3d_18-b3b3357e.pth" in err
    rc, out, err = _run(capsys, "weights", "verify", backbone_file)
    assert rc == 0 and "ok (backbone" in out


def test_seamless_score_is_marked_and_equals_api(capsys, pair, weights_file, backbone_file):
    ref, test = pair
    rc, out, err = _run(capsys, "score", "--ref", ref, "--test", test, "--weights", weights_file,
                        "--backbone", backbone_file, "--seamless", "--json")
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["mode"].startswith("seamless") and doc["provenance"]["mode"] == "seamless"
    api = CGVQM(weights=weights_file, backbone=backbone_file, seamless=True).score(ref, test)
    assert doc["q"] == pytest.approx(api.q, abs=1e-9)
    upstream = CGVQM(weights=weights_file, backbone=backbone_file).score(ref, test)
    assert abs(api.q - upstream.q) > 1e-6
    rc, _, err = _run(capsys, "score", "--ref", ref, "--test", test, "--weights", weights_file,
                      "--backbone", backbone_file, "--seamless", "--emap", "x.mkv")
    assert rc == 2 and "seamless" in err


def test_score_timing_says_where_the_time_went(capsys, pair, weights_file, backbone_file):
    """--timing: one line on stderr and the stages in the JSON, adding up to the wall time;
    the score itself is the one without it. Refused for a peer metric."""
    ref, test = pair
    rc, out, err = _run(capsys, "score", "--ref", ref, "--test", test, "--weights", weights_file,
                        "--backbone", backbone_file, "--json", "--timing")
    assert rc == 0, err
    doc = json.loads(out)
    t = doc["timing"]
    assert set(t) == {"decode", "wait", "copy", "backbone", "pooling", "idle", "wall"}
    assert t["decode"] + t["copy"] + t["backbone"] + t["pooling"] + t["idle"] == \
        pytest.approx(t["wall"], abs=1e-5)
    assert t["backbone"] > 0 and t["decode"] > 0
    assert "timing: wall" in err and "backbone" in err
    plain = CGVQM(weights=weights_file, backbone=backbone_file).score(ref, test)
    assert doc["q"] == plain.q
    rc, out, err = _run(capsys, "score", "--metric", "psnr", "--ref", ref, "--test", test,
                        "--timing")
    assert rc == 2 and err.strip().splitlines()[-1].endswith(
        "--timing is offered for CGVQM only, not psnr")
