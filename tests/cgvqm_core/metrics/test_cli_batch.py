"""``cgvqm metrics``, ``cgvqm score --metric`` and ``cgvqm batch --metrics``: the registry on
the command line, the scores contract with direction and provenance, resume keys, sha256
checks, metrics not applicable at a size."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from cgvqm_core.batch import SCORE_COLUMNS, WorkUnit, manifest_units, run_unit
from cgvqm_core.cli import main
from cgvqm_core.metrics import MetricOptions
from stimuli_manifests import fill_checksums, load_manifest, save_manifest, write_video
from stimuli_manifests.tables import SCORES, read_table

from .conftest import blurred, noisy, real_video

FPS = 8
DONE_WHEN = ["psnr", "ssim", "ms-ssim", "iw-ssim", "vif", "fsim", "sr-sim", "gmsd", "ms-gmsd",
             "vsi", "dss", "haarpsi", "mdsi", "flip", "cvvdp"]


def _run(capsys, *args) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def _study(tmp_path: Path, size: int = 48, checksums: bool = True) -> Path:
    root = tmp_path / "videos"
    refs, conds = [], []
    for r, image in enumerate(("astronaut", "coffee")):
        ref = real_video(6, size, size, image=image)
        write_video(root / f"src{r}.mkv", ref, FPS)
        refs.append({"path": f"src{r}.mkv", "scene": image})
        for lv in (1, 2):
            v = noisy(ref, 6.0 * lv, seed=lv) if r == 0 else blurred(ref, 0.8 * lv)
            write_video(root / f"src{r}_d{lv}.mkv", v, FPS)
            conds.append({"reference": f"SRC{r + 1:02d}", "path": f"src{r}_d{lv}.mkv",
                          "method": "noise" if r == 0 else "blur", "level": lv})
    doc = {"format": "cgvq-manifest/1", "study_id": "t", "root": "videos",
           "references": refs, "conditions": conds}
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(doc))
    if checksums:
        save_manifest(fill_checksums(load_manifest(path)), path)
    return path


def test_metrics_lists_registry_with_availability(capsys):
    rc, out, _ = _run(capsys, "metrics", "--json")
    assert rc == 0
    rows = {r["name"]: r for r in json.loads(out)}
    for name in DONE_WHEN:
        assert rows[name]["available"], (name, rows[name]["reason"])
    assert rows["gmsd"]["direction"] == "lower-better"
    assert rows["cvvdp"]["kind"] == "video" and rows["ssim"]["kind"] == "image"
    for name in ("lpips", "dists", "pieapp", "vmaf"):
        assert name in rows and (rows[name]["available"] or rows[name]["reason"])
    rc, out, _ = _run(capsys, "metrics")
    assert rc == 0 and "ms-ssim" in out and "lower-better" in out


def _cgvqm_rows(capsys) -> dict[str, str]:
    rc, out, _ = _run(capsys, "metrics")
    assert rc == 0
    return {line.split()[0]: line.split(None, 4)[4] for line in out.splitlines()
            if line.startswith("cgvqm-")}


def test_metrics_says_where_cgvqm_files_are_missing_offline(capsys, tmp_path, monkeypatch):
    """Offline, CGVQM is available only once its published weights and the backbone are in
    their caches (or given): each missing file is named, in the order score would meet them;
    online, missing files are fetched on first use, and said so."""
    rows = _cgvqm_rows(capsys)  # the test's caches are empty and CGVQM_OFFLINE is set
    assert rows["cgvqm-2"].startswith("no: the published cgvqm-2 weights (cgvqm-2.pickle)")
    assert "cgvqm weights fetch --from DIR" in rows["cgvqm-2"]
    cache = tmp_path / "cgvqm-cache"
    cache.mkdir(exist_ok=True)
    (cache / "cgvqm-2.pickle").write_bytes(b"placed by the test")
    rows = _cgvqm_rows(capsys)
    assert rows["cgvqm-2"].startswith("no: the R3D-18 backbone (r3d_18-b3b3357e.pth")
    assert rows["cgvqm-5"].startswith("no: the published cgvqm-5 weights")
    monkeypatch.setenv("CGVQM_BACKBONE", str(tmp_path / "backbone.pth"))
    rows = _cgvqm_rows(capsys)
    assert rows["cgvqm-2"] == "yes" and rows["cgvqm-5"].startswith("no: the published cgvqm-5")
    monkeypatch.delenv("CGVQM_BACKBONE")
    monkeypatch.delenv("CGVQM_OFFLINE")
    rows = _cgvqm_rows(capsys)
    assert rows["cgvqm-2"] == "yes (downloads the R3D-18 backbone on first use)"
    assert rows["cgvqm-5"] == ("yes (downloads the published weights and the R3D-18 backbone "
                               "on first use)")


def test_score_peer_metric(capsys, tmp_path):
    ref = real_video(4, 40, 48)
    r = write_video(tmp_path / "r.mkv", ref, FPS)
    t = write_video(tmp_path / "t.mkv", noisy(ref, 10), FPS)
    rc, out, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "psnr", "--json")
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["metric"] == "psnr" and doc["direction"] == "higher-better"
    assert 20 < doc["score"] < 40 and len(doc["per_frame"]) == 4
    rc, out, _ = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "ms-ssim")
    assert rc == 0 and "not applicable at 48x40" in out
    rc, _, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "nope")
    assert rc == 2 and "unknown metric 'nope'" in err
    rc, _, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "lpips")
    assert rc == 2 and "not available here" in err
    rc, _, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "flip", "--ppd",
                      "-3")
    assert rc == 2 and "positive" in err


def test_batch_writes_contract_and_resumes(capsys, tmp_path):
    manifest = _study(tmp_path)
    out = tmp_path / "scores.csv"
    base = ["batch", "--manifest", manifest, "--out", out, "--random-backbone", "0",
            "--weights", "uniform"]
    rc, stdout, err = _run(capsys, *base, "--metrics", "psnr,gmsd,ms-ssim,cgvqm-2")
    assert rc == 0, err
    rows = read_table(out, SCORES)  # the versioned contract reads it
    header = next(csv.reader(out.open()))
    assert tuple(header) == SCORE_COLUMNS and header[-1] == "format"
    assert len(rows) == 4 * 4
    by = {(r["stimulus"], r["metric"]): r for r in rows}
    assert by[("SRC01_HRC01", "psnr")]["direction"] == "higher-better"
    assert by[("SRC01_HRC01", "gmsd")]["direction"] == "lower-better"
    na = by[("SRC01_HRC01", "ms-ssim")]
    assert na["score"] == "" and na["note"].startswith("not applicable at 48x48")
    assert "ms-ssim: not applicable" in stdout
    cg = by[("SRC01_HRC01", "cgvqm-2-uniform")]
    assert cg["backbone"] == "random-seed-0" and cg["pooling"] == "max"
    assert json.loads(cg["settings"])["patch_scale"] == 4
    assert json.loads(by[("SRC01_HRC01", "psnr")]["versions"])["implementation"]
    assert len({r["key"] for r in rows}) == len(rows)
    # level 2 has twice the noise of level 1: worse in each metric's direction
    assert float(by[("SRC01_HRC01", "psnr")]["score"]) > float(by[("SRC01_HRC02", "psnr")]
                                                               ["score"])
    assert float(by[("SRC01_HRC01", "gmsd")]["score"]) < float(by[("SRC01_HRC02", "gmsd")]
                                                               ["score"])
    # rerun: nothing new
    rc, stdout, _ = _run(capsys, *base, "--metrics", "psnr,gmsd,ms-ssim,cgvqm-2")
    assert "0 scored, 4 already" in stdout
    # a new metric appends its rows; the unchanged ones stay (without CGVQM's options, which
    # neither metric reads: they would be refused)
    rc, stdout, _ = _run(capsys, *base[:5], "--metrics", "psnr,flip", "--ppd", "40")
    # a setting that changes numbers (FLIP's ppd) would give a second row per stimulus, of
    # which the analysis keeps one: refused, to be written to a new file
    rc, _, err = _run(capsys, *base[:5], "--metrics", "psnr,flip", "--ppd", "60")
    assert rc == 2 and "use a new --out" in err and err.count("cgvqm: error") == 1
    other = tmp_path / "ppd60.csv"
    rc, stdout, _ = _run(capsys, *base[:4], other, "--metrics", "psnr,flip", "--ppd", "60")
    rows = read_table(out, SCORES)
    flips = [r for r in rows if r["metric"] == "flip"]
    assert len(flips) == 4 and {json.loads(r["settings"])["ppd"] for r in flips} == {40}
    assert sum(r["metric"] == "psnr" for r in rows) == 4
    flips60 = [r for r in read_table(other, SCORES) if r["metric"] == "flip"]
    assert len(flips60) == 4 and {json.loads(r["settings"])["ppd"] for r in flips60} == {60}


def test_batch_refuses_a_changed_stimulus(capsys, tmp_path):
    manifest = _study(tmp_path)
    victim = tmp_path / "videos" / "src1_d2.mkv"
    victim.write_bytes(victim.read_bytes()[:-100])  # truncated after checksumming
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", tmp_path / "s.csv",
                      "--metrics", "psnr")
    assert rc == 2 and "src1_d2.mkv" in err and "sha256" in err
    assert not (tmp_path / "s.csv").exists() or (tmp_path / "s.csv").stat().st_size < 400


def test_batch_refuses_an_old_layout(capsys, tmp_path):
    manifest = _study(tmp_path)
    old = tmp_path / "old.csv"
    old.write_text("stimulus,reference,metric,score\nA,B,psnr,30\n")
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", old, "--metrics", "psnr")
    assert rc == 2 and "choose another --out" in err


def test_work_unit_is_portable_and_keys_cover_inputs(tmp_path):
    manifest = _study(tmp_path)
    opts = MetricOptions()
    units = manifest_units(manifest, ["psnr"], opts, progress=False)
    assert len(units) == 2 and all(len(u.tests) == 2 for u in units)
    u = WorkUnit.from_dict(json.loads(json.dumps(units[0].to_dict())))  # plain data only
    rows = run_unit(u)  # builds its own scorers and verifies the inputs itself
    assert [r["stimulus"] for r in rows] == ["SRC01_HRC01", "SRC01_HRC02"]
    again = run_unit(u, done={r["key"] for r in rows})
    assert again == []
    # a different input content is a different key
    other = WorkUnit.from_dict(u.to_dict())
    other.tests[0] = type(other.tests[0])(other.tests[0].id, other.tests[1].path,
                                          other.tests[1].sha256)
    rows2 = run_unit(other, done={r["key"] for r in rows})
    assert [r["stimulus"] for r in rows2] == ["SRC01_HRC01"]
    bad = WorkUnit.from_dict(u.to_dict())
    bad.tests[0] = type(bad.tests[0])(bad.tests[0].id, bad.tests[0].path, "0" * 64)
    with pytest.raises(Exception, match="sha256"):
        run_unit(bad)
