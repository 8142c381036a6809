"""A researcher's own renders through the whole toolkit: ``cgvq-study init`` builds the study,
a participant rates in the real app (Xvfb, xdotool), more raters are simulated, ``cgvqm
batch`` scores it and ``cgvq-analyze report`` reads it all, every tool on the init'd folder
unchanged."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from session_store import SessionStore
from stimuli_manifests import load_manifest, write_video

pytestmark = pytest.mark.gui
FPS = 30


def _cli(module: str, *args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def _renders(folder: Path) -> None:
    """Two scenes, each a smooth moving pattern; test videos add noise of two strengths."""
    rng = np.random.default_rng(3)
    _, x = np.mgrid[0:64, 0:80].astype(np.float32)
    for s, scene in enumerate(("sponza", "bistro")):
        ref = np.stack([np.stack([128 + 100 * np.sin((x + 3 * t + 20 * s) / 9.0)] * 3, -1)
                        for t in range(15)])
        write_video(folder / scene / "reference.mkv", ref.clip(0, 255).astype(np.uint8), FPS)
        for level, sigma in ((1, 40.0), (2, 10.0)):
            noisy = ref + rng.normal(0, sigma, ref.shape)
            write_video(folder / scene / f"pathtrace_L{level}.mkv",
                        noisy.clip(0, 255).astype(np.uint8), FPS)


@pytest.mark.slow  # about 24 s: CI runs it after `make test` (.ci/run), as does `make test-slow`
def test_init_study_is_run_scored_and_analysed(tmp_path, xdisplay, app_driver):
    renders, study = tmp_path / "renders", tmp_path / "study"
    _renders(renders)
    res = _cli("cgvq_cli.study_cli", "init", renders, "--out", study, "--min-display", "640x480")
    assert res.returncode == 0, res.stdout + res.stderr
    res = _cli("cgvq_cli.study_cli", "check", study)
    assert res.returncode == 0 and "OK: the study folder is ready" in res.stdout, res.stdout
    manifest = load_manifest(study / "manifest.json").manifest
    ids = {s.id for s in manifest.stimuli()}
    assert ids == {"sponza", "bistro", "sponza_pathtrace_L1", "sponza_pathtrace_L2",
                   "bistro_pathtrace_L1", "bistro_pathtrace_L2"}

    # a participant rates the first trial in the real app, then quits
    app = app_driver(xdisplay, [str(study), "--participant", "P01", "--practice", "0",
                                "--seed", "1", "--max-dropped-frames", "-1",
                                "--pilot-no-vsync"])
    app.wait("preflight-passed")
    app.key("space")
    app.wait("viewing trial=0")  # no briefing or consent text in this study
    app.open_rating(min_view_s=0.6)
    app.key("Right", "Return")
    app.wait("recorded trial=0")
    app.wait("viewing trial=1")
    app.key("p")
    app.wait("pause")
    code, _ = app.quit_confirmed()
    assert code == 0
    with SessionStore.open(study / "sessions" / "P01.sqlite") as store:
        rows = store.ratings()
    assert len(rows) == 1 and rows[0]["stimulus"] in ids

    res = _cli("cgvq_cli.study_cli", "simulate", "--manifest", study / "manifest.json",
               "--raters", 6, "--out", tmp_path / "simulated", "--no-progress")
    assert res.returncode == 0, res.stderr
    scores = tmp_path / "scores.csv"
    res = _cli("cgvqm_core.cli", "batch", "--manifest", study / "manifest.json", "--out", scores,
               "--random-backbone", 0, "--weights", "uniform")
    assert res.returncode == 0, res.stderr
    with open(scores, newline="") as fh:
        scored = {r["stimulus"]: r for r in csv.DictReader(fh)}
    conditions = {str(c.id): c for c in manifest.conditions}
    assert set(scored) == set(conditions)
    for sid, row in scored.items():  # scored from the study's own copies
        assert row["stimulus_sha256"] == conditions[sid].sha256

    report = tmp_path / "report"
    res = _cli("analysis.cli", "report", "--sessions", study / "sessions", tmp_path / "simulated",
               "--manifest", study / "manifest.json", "--metric", scores, "--out", report,
               "--bootstrap", 50, "--splits", 50, "--min-completeness", 0)
    assert res.returncode == 0, res.stderr
    with open(report / "dmos.csv", newline="") as fh:
        dmos = {r["stimulus"]: r for r in csv.DictReader(fh)}
    assert ids <= set(dmos)
    # the analysis recovers the rendered truth: the stronger noise (level 1) rates lower
    for scene in ("sponza", "bistro"):
        assert float(dmos[f"{scene}_pathtrace_L1"]["dmos"]) < float(
            dmos[f"{scene}_pathtrace_L2"]["dmos"])
