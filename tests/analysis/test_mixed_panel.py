"""The issue's "Done when": a mixed panel gives a report whose first screen names the foreign
session refused, the partial session and the removed random rater, keeping the consistent
raters with an offset.

On real data (SUREAL's NFLX panel, ../shared) turned into session files, with injected raters
of known kind; and on a generated panel that runs everywhere.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.cli import main
from analysis.sureal_io import load_sureal
from analysis.synthetic import synthetic_study
from stimuli_manifests import load_manifest, parse_manifest, save_manifest

from .conftest import write_session

pytest.importorskip("session_store")

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "analysis"


def screenshot(html: Path, name: str, height: int = 1400) -> Path | None:
    """Render report.html with headless Chromium into test-artifacts/analysis/ (when
    Chromium is installed) so a person can look at it."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        return None
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    out = ARTIFACTS / name
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    f"--window-size=1280,{height}", f"--screenshot={out}", html.as_uri()],
                   capture_output=True, timeout=120, check=False)
    return out if out.is_file() else None


def _glance(html: str) -> str:
    start = html.index("At a glance")
    return html[start: html.index("</div>", start)]


def _rows(participant: str, stimuli: pd.DataFrame, votes: np.ndarray) -> pd.DataFrame:
    ok = np.isfinite(votes)
    return pd.DataFrame({"participant": participant, "stimulus": stimuli.index[ok],
                         "reference": stimuli["reference"].to_numpy()[ok], "repetition": 1,
                         "is_hidden_reference": stimuli["is_hidden_reference"].to_numpy()[ok],
                         "rating": votes[ok]})


def _check_report(out: Path, *, foreign: str, partial: str, removed: set[str],
                  offsets: set[str]) -> None:
    html = (out / "report.html").read_text()
    glance = _glance(html)
    assert foreign in glance and "other-study" in glance
    assert partial in glance and "below --min-completeness" in glance
    for r in removed:
        assert r in glance
    summary = json.loads((out / "summary.json").read_text())
    assert {r["rater"] for r in summary["removed_raters"]} == removed
    used = {row["rater"] for row in summary["data_quality"] if row["status"] == "used"}
    assert offsets <= used
    assert not offsets & set(glance.split("removed by the screening")[-1].split("</ul>")[0]
                             .split())


@pytest.mark.slow  # 10 s; the generated panel covers the same rules by default
def test_mixed_panel_on_nflx_with_injected_raters(sureal_dir: Path, tmp_path: Path,
                                                  capsys) -> None:
    rs = load_sureal(sureal_dir / "NFLX_dataset_public_raw.py")
    st = rs.stimuli
    manifest = parse_manifest({
        "format": "cgvq-manifest/1", "study_id": "nflx-public",
        "scale": {"min": 1, "max": 5, "labels": []},
        "protocol": {"repetitions": 1},
        "references": [{"id": r, "path": f"{r}.yuv"} for r in dict.fromkeys(st["reference"])],
        "conditions": [{"id": s, "reference": row["reference"], "path": f"{s}.yuv",
                        "method": "encode", "level": 0}
                       for s, row in st.iterrows() if not row["is_hidden_reference"]],
    })
    mpath = save_manifest(manifest, tmp_path / "manifest.json")
    sha = load_manifest(mpath).sha256
    trials = [(s.id, s.reference, 1, s.is_hidden_reference) for s in manifest.stimuli()]
    order = {t[0]: k for k, t in enumerate(trials)}
    stimuli = st.loc[sorted(st.index, key=order.__getitem__)]
    base = rs.scores[:, :, 0][[rs.stimulus_ids.index(s) for s in stimuli.index]]
    folder = tmp_path / "sessions"
    folder.mkdir()
    for k in range(rs.n_raters):
        write_session(folder / f"R{k:02d}.sqlite", _rows(f"R{k:02d}", stimuli, base[:, k]),
                      study_id="nflx-public", manifest_sha256=sha, all_trials=trials)
    rng = np.random.default_rng(5)
    n = len(stimuli)
    mos = np.nanmean(base, axis=1)
    injected = {
        "Xrandom": rng.integers(1, 6, n).astype(float),
        "Xinverted": np.clip(np.round(6 - mos + rng.normal(0, 0.5, n)), 1, 5),
        "Xoffset1": np.clip(base[:, 3] - 1, 1, 5),
        "Xoffset2": np.clip(base[:, 7] - 1, 1, 5),
    }
    for name, votes in injected.items():
        write_session(folder / f"{name}.sqlite", _rows(name, stimuli, votes),
                      study_id="nflx-public", manifest_sha256=sha, all_trials=trials)
    partial = _rows("Xpartial", stimuli, base[:, 11]).iloc[:20]  # 20 of 79 trials
    write_session(folder / "Xpartial.sqlite", partial, study_id="nflx-public",
                  manifest_sha256=sha, all_trials=trials, finish=False)
    # A session of another study whose participant id collides, in a file sorting first.
    write_session(folder / "A_foreign.sqlite", _rows("R05", stimuli, rng.integers(1, 6, n)
                                                     .astype(float)),
                  study_id="other-study", manifest_sha256=None)
    out = tmp_path / "report"
    assert main(["report", "--manifest", str(mpath), "--sessions", str(folder),
                 "--bootstrap", "100", "--splits", "100", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "A_foreign.sqlite" in err
    _check_report(out, foreign="A_foreign.sqlite", partial="Xpartial",
                  removed={"Xrandom", "Xinverted"}, offsets={"Xoffset1", "Xoffset2"})
    screenshot(out / "report.html", "nflx_mixed_panel_first_screen.png", 1100)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_raters_used"] == rs.n_raters + 2  # the 26 + the two offset raters
    partial_row = next(x for x in summary["exclusions"] if x["who"] == "Xpartial")
    assert "20 of 79 planned trials" in partial_row["reason"]


@pytest.mark.slow  # about 10 s here: CI runs it after `make test` (.ci/run)
def test_mixed_panel_generated(tmp_path: Path) -> None:
    """The same scenario on a generated panel (runs without ../shared)."""
    st = synthetic_study(n_scenes=4, methods=("blur", "noise"), levels=3, n_raters=10,
                         repetitions=2, noise_sd=7, bias_sd=4, seed=12,
                         special={"Xrandom": "random", "Xoffset1": "offset:-20",
                                  "Xoffset2": "offset:-20", "Xpartial": "partial:0.26"})
    mpath = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    sha = load_manifest(mpath).sha256
    trials = [(s.id, s.reference, rep, s.is_hidden_reference)
              for rep in (1, 2) for s in st.manifest.manifest.stimuli()]
    folder = tmp_path / "sessions"
    folder.mkdir()
    for rater, rows in st.ratings.groupby("participant"):
        write_session(folder / f"{rater}.sqlite", rows, study_id="synthetic",
                      manifest_sha256=sha, all_trials=trials,
                      finish=rater != "Xpartial")
    other = synthetic_study(n_scenes=4, methods=("blur", "noise"), levels=3, n_raters=1,
                            repetitions=2, seed=77, study_id="other-study")
    write_session(folder / "A_foreign.sqlite", other.ratings, study_id="other-study",
                  manifest_sha256=None)
    out = tmp_path / "report"
    assert main(["report", "--manifest", str(mpath), "--sessions", str(folder), "--model",
                 "p910", "--bootstrap", "100", "--splits", "100", "--out", str(out)]) == 0
    _check_report(out, foreign="A_foreign.sqlite", partial="Xpartial",
                  removed={"Xrandom"}, offsets={"Xoffset1", "Xoffset2"})
    screenshot(out / "report.html", "generated_mixed_panel_report.png", 9000)
