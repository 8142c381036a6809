"""Audit fixes of the scores CSV that ``cgvqm batch`` and ``score --csv`` write: rows flushed
per group, one row per (metric, pooling, stimulus), the toolkit's version in the resume key,
unreadable or torn files, and the odd-size error map the docs describe."""

from __future__ import annotations

import csv
import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import cgvqm_core.metrics.engine as engine
from cgvqm_core.batch import SCORE_COLUMNS, row_key, score_manifest, scorer_identity
from cgvqm_core.metrics import MetricOptions, build_scorers
from cgvqm_core.version import __version__

from .metrics.test_cli_batch import _run, _study

DOCS = Path(__file__).resolve().parents[2] / "docs"
CGVQM_ARGS = ["--random-backbone", "0", "--weights", "uniform"]


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.open(newline="", encoding="utf-8")))


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR by hand: mean over frames of 10 log10(1 / MSE) on [0, 1] RGB."""
    x, y = a.astype(np.float64) / 255, b.astype(np.float64) / 255
    mse = ((x - y) ** 2).reshape(len(x), -1).mean(axis=1)
    return float(np.mean(10 * np.log10(1.0 / mse)))


# -- finding 3: rows flushed per group -------------------------------------------------------

def test_an_interrupt_keeps_the_groups_already_scored(tmp_path, monkeypatch):
    manifest = _study(tmp_path)
    out = tmp_path / "s.csv"
    real = engine.score_reference
    calls = {"n": 0}

    def interrupted_second(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:  # Ctrl-C while SRC01's second test (its 2nd group) is scored
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(engine, "score_reference", interrupted_second)
    with pytest.raises(KeyboardInterrupt):
        score_manifest(manifest, out, ["psnr"], group_size=1, progress=False)
    rows = _rows(out)
    assert [r["stimulus"] for r in rows] == ["SRC01_HRC01"]
    monkeypatch.setattr(engine, "score_reference", real)
    s = score_manifest(manifest, out, ["psnr"], group_size=1, progress=False)
    assert (s.scored, s.skipped) == (3, 1) and len(_rows(out)) == 4


def test_sigterm_stops_a_batch_as_ctrl_c_does_and_says_so(tmp_path, capsys, monkeypatch):
    """A job scheduler or `timeout` sends SIGTERM: the batch ends with the same line as
    Ctrl-C (exit 143), the groups already scored stay, and the handler is gone afterwards."""
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        pytest.skip("this test runner handles SIGTERM itself")
    manifest = _study(tmp_path)
    out = tmp_path / "s.csv"
    real = engine.score_reference
    calls = {"n": 0}

    def terminated_second(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(30)  # the handler raises here at once
        return real(*a, **k)

    monkeypatch.setattr(engine, "score_reference", terminated_second)
    args = ["batch", "--manifest", manifest, "--out", out, "--metrics", "psnr",
            "--group-size", "1"]
    rc, _, err = _run(capsys, *args)
    assert rc == 128 + signal.SIGTERM
    assert err.splitlines()[-1] == ("cgvqm: stopped by SIGTERM: interrupted (batch runs "
                                    "resume where they stopped)")
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    assert [r["stimulus"] for r in _rows(out)] == ["SRC01_HRC01"]
    monkeypatch.setattr(engine, "score_reference", real)
    rc, out_text, err = _run(capsys, *args)
    assert rc == 0 and out_text.startswith("3 scored, 1 already"), err


def test_a_batch_logged_to_a_file_gets_lines_not_bar_redraws(tmp_path, capsys, monkeypatch):
    """stderr redirected to a log: whole lines, at most one per half minute and one at the
    end, none of tqdm's carriage-return redraws."""
    from cgvqm_core import progress

    clock = {"t": 0.0}
    monkeypatch.setattr(progress, "monotonic", lambda: clock["t"])
    real = engine.score_reference

    def slow(*a, **k):  # each group takes 20 s on the clock
        clock["t"] += 20.0
        return real(*a, **k)

    monkeypatch.setattr(engine, "score_reference", slow)
    rc, out, err = _run(capsys, "batch", "--manifest", _study(tmp_path), "--out",
                        tmp_path / "s.csv", "--metrics", "psnr", "--group-size", "1")
    assert rc == 0 and out.startswith("4 scored"), err
    assert "\r" not in err
    lines = [line for line in err.splitlines() if line.startswith("cgvqm batch:")]
    # groups end at 20, 40, 60 and 80 s: a line at 40 s (30 s since the start), at 80 s
    # (40 s since that line), and none at the end (nothing new since)
    assert lines == ["cgvqm batch: 2 of 4 videos (50 %), 40 s",
                     "cgvqm batch: 4 of 4 videos (100 %), 1 min 20 s"]


# -- finding 4: one row per (metric, pooling, stimulus) --------------------------------------

def test_batch_with_other_settings_into_the_same_file_is_refused(tmp_path, capsys,
                                                                 monkeypatch):
    manifest = _study(tmp_path)
    out = tmp_path / "s.csv"
    base = ["batch", "--manifest", manifest, "--out", out, *CGVQM_ARGS]
    rc, _, err = _run(capsys, *base, "--patch-scale", "2")
    assert rc == 0, err
    before = out.read_bytes()
    monkeypatch.setattr(engine, "score_reference", _never)
    rc, _, err = _run(capsys, *base)  # patch scale 4: other keys for the same stimuli
    assert rc == 2 and err.count("cgvqm: error") == 1
    assert str(out) in err and "use a new --out" in err
    assert out.read_bytes() == before


def _never(*a, **k):
    raise AssertionError("scored although the run had to be refused first")


def test_score_csv_twice_keeps_one_row(tmp_path, capsys, monkeypatch):
    from stimuli_manifests import write_video

    rng = np.random.default_rng(0)
    ref = rng.integers(0, 256, (4, 32, 32, 3), dtype=np.uint8)
    test = np.clip(ref + rng.normal(0, 8, ref.shape), 0, 255).astype(np.uint8)
    r = write_video(tmp_path / "r.mkv", ref, 8)
    t = write_video(tmp_path / "t.mkv", test, 8)
    out = tmp_path / "s.csv"
    args = ["score", "--ref", r, "--test", t, "--metric", "psnr", "--csv", out]
    rc, _, err = _run(capsys, *args)
    assert rc == 0, err
    (row,) = _rows(out)
    assert float(row["score"]) == pytest.approx(_psnr(ref, test), abs=1e-4)  # lossless mkv
    monkeypatch.setattr(engine, "score_reference", _never)
    rc, _, err = _run(capsys, *args)
    assert rc == 2 and err.count("\n") == 1 and "use a new --csv" in err
    assert len(_rows(out)) == 1


def test_each_row_carries_its_own_metrics_key(tmp_path):
    """ms-ssim does not apply at 48x48 and the image pass lists it first: its row must still
    get its own key, so that psnr alone (a second computation) finds psnr's rows."""
    manifest = _study(tmp_path)
    score_manifest(manifest, tmp_path / "a.csv", ["psnr", "ms-ssim"], progress=False)
    score_manifest(manifest, tmp_path / "b.csv", ["psnr"], progress=False)
    both = {r["stimulus"]: r["key"] for r in _rows(tmp_path / "a.csv") if r["metric"] == "psnr"}
    alone = {r["stimulus"]: r["key"] for r in _rows(tmp_path / "b.csv")}
    assert both == alone


# -- finding 5: the toolkit's version in the key and the CSV ---------------------------------

def test_the_cgvqm_core_version_enters_the_key_and_the_csv(tmp_path, monkeypatch):
    options = MetricOptions(random_backbone=0, weights="uniform")
    (scorer,) = build_scorers(["cgvqm-2"], options)
    assert scorer.provenance()["cgvqm_core"] == __version__
    from cgvqm_core.batch import InputFile

    ref, test = InputFile("R", "r", "a" * 64), InputFile("T", "t", "b" * 64)
    key = row_key(scorer_identity(scorer, options), "max", ref, test)
    monkeypatch.setattr("cgvqm_core.metric.__version__", "99.0.0")
    upgraded = row_key(scorer_identity(scorer, options), "max", ref, test)
    assert upgraded != key
    manifest = _study(tmp_path)
    score_manifest(manifest, tmp_path / "s.csv", ["cgvqm-2"], options, progress=False)
    assert {json.loads(r["versions"])["cgvqm_core"] for r in _rows(tmp_path / "s.csv")} == {
        "99.0.0"}


# -- finding 6: unreadable outputs -----------------------------------------------------------

def test_a_utf16_out_or_csv_is_refused_in_one_line_before_scoring(tmp_path, capsys,
                                                                  monkeypatch):
    manifest = _study(tmp_path)
    bad = tmp_path / "utf16.csv"
    bad.write_bytes(",".join(SCORE_COLUMNS).encode("utf-16"))
    monkeypatch.setattr(engine, "score_reference", _never)
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", bad, "--metrics",
                      "psnr")
    assert rc == 2 and err.count("\n") == 1 and "not UTF-8" in err and "--out" in err
    videos = tmp_path / "videos"
    rc, _, err = _run(capsys, "score", "--ref", videos / "src0.mkv", "--test",
                      videos / "src0_d1.mkv", "--metric", "psnr", "--csv", bad)
    assert rc == 2 and err.count("\n") == 1 and "not UTF-8" in err and "--csv" in err


def test_an_out_folder_is_refused_before_any_scoring(tmp_path, capsys, monkeypatch):
    manifest = _study(tmp_path)
    folder = tmp_path / "scores"
    folder.mkdir()
    monkeypatch.setattr(engine, "score_reference", _never)
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", folder, "--metrics",
                      "psnr")
    assert rc == 2 and err.count("\n") == 1 and "is a folder" in err


# -- finding 7: a torn last row --------------------------------------------------------------

@pytest.mark.parametrize("cut", [40, 2])  # inside the last row; only its line end lost
def test_a_torn_last_row_is_dropped_and_scored_again(tmp_path, capsys, cut):
    manifest = _study(tmp_path)
    out = tmp_path / "s.csv"
    base = ["batch", "--manifest", manifest, "--out", out, "--metrics", "psnr"]
    assert _run(capsys, *base)[0] == 0
    whole = {r["stimulus"]: r["score"] for r in _rows(out)}
    out.write_bytes(out.read_bytes()[:-cut])  # killed while writing the last row
    rc, stdout, err = _run(capsys, *base)
    assert rc == 0 and "unfinished" in err and "1 scored, 3 already" in stdout
    text = out.read_text(encoding="utf-8")
    lines = list(csv.reader(text.splitlines()))
    assert all(len(x) == len(SCORE_COLUMNS) for x in lines) and len(lines) == 5
    assert {r["stimulus"]: r["score"] for r in _rows(out)} == whole
    assert len(pd.read_csv(out)) == 4


# -- finding 10: the error map of an odd-sized video -----------------------------------------

def test_odd_sized_mp4_error_map_is_padded_and_documented(tmp_path):
    import av

    from cgvqm_core.metric import CGVQM

    rng = np.random.default_rng(0)
    ref = rng.integers(0, 256, (8, 31, 33, 3), dtype=np.uint8)
    test = np.clip(ref + rng.normal(0, 10, ref.shape), 0, 255).astype(np.uint8)
    metric = CGVQM(random_backbone=0, weights="uniform")
    sizes = {}
    for name in ("e.mp4", "e.mkv"):
        metric.score(ref, test, fps=8, emap=tmp_path / name)
        with av.open(str(tmp_path / name)) as c:
            frame = next(c.decode(video=0)).to_ndarray(format="rgb24")
        sizes[name] = frame.shape[:2]
    assert sizes == {"e.mp4": (32, 34), "e.mkv": (31, 33)}
    doc = " ".join((DOCS / "cgvqm.md").read_text().split())
    assert "padded by one edge row or column" in doc


def test_file_formats_describes_the_weights_layout_the_loader_reads():
    doc = " ".join((DOCS / "file-formats.md").read_text().split())
    assert "one flat list" in doc and "provenance.anchoring" in doc
