"""Adaptive (unbalanced) designs: the allocation policy, the subsets ICC and screening use,
completeness of adaptive raters, and what the report says about ratings per stimulus.

Ratings come from a known generative model (``clip(Q(v) + b_s + e, 0, 100)``, as in
benchmarks/bench_coverage.py): block 1 gives every stimulus one rating per rater, later
blocks give some stimuli extra ratings from some raters. Expected values are computed here
directly from the tidy rows or the repetition-0 matrix, never from the code under test.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.data import RatingSet, balanced_subset
from analysis.inputs import load_ratings, ratings_from_frame
from analysis.pipeline import AnalysisConfig, run_analysis
from analysis.reliability import icc_from_long, reliability
from analysis.report import write_report
from analysis.screening import screen_raters
from analysis.screening.grubbs import rater_deviation
from analysis.synthetic import synthetic_study
from stimuli_manifests import LoadedManifest, load_manifest, parse_manifest, save_manifest

from .conftest import write_session

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "analysis" / "adaptive"
N_SCENES, LEVELS, N_RATERS = 4, 3, 8
BLOCK1 = "first rating of each stimulus per rater (block 1 of an adaptive design)"


def _manifest(allocation: str = "adaptive", repetitions: int = 3) -> LoadedManifest:
    """N_SCENES references x one method x LEVELS levels (the videos are never read)."""
    refs = [{"id": f"SRC{i + 1:02d}", "path": f"s{i}.mkv", "scene": f"scene{i + 1}"}
            for i in range(N_SCENES)]
    conds = [{"reference": r["id"], "path": f"{r['id']}_{lv}.mkv", "method": "blur",
              "level": lv} for r in refs for lv in range(1, LEVELS + 1)]
    protocol: dict = {"repetitions": repetitions, "allocation": allocation}
    if allocation == "adaptive":
        protocol["adaptive"] = {"blocks": 3, "max_per_block": 2}
    m = parse_manifest({"format": "cgvq-manifest/1", "study_id": "adaptive-test",
                        "protocol": protocol, "references": refs, "conditions": conds})
    return LoadedManifest(m, None, Path("."))


def _ratings(loaded: LoadedManifest, *, extra: bool = True, seed: int = 7) -> pd.DataFrame:
    """Tidy rows: block 1 (every stimulus once per rater), then, when ``extra``, 1 or 2 more
    ratings of a rater-specific random third of the stimuli (the later blocks)."""
    rng = np.random.default_rng(seed)
    stimuli = loaded.manifest.stimuli()
    ref_q = {r.id: rng.uniform(75, 85) for r in loaded.manifest.references}
    q = {s.id: ref_q[s.reference] - (0 if s.is_hidden_reference else 12.0 * (LEVELS + 1 -
                                                                          s.level))
         for s in stimuli}
    bias = rng.normal(0, 4, N_RATERS)
    rows = []
    for k in range(N_RATERS):
        counts = np.ones(len(stimuli), dtype=int)
        if extra:
            chosen = rng.choice(len(stimuli), len(stimuli) // 3, replace=False)
            counts[chosen] += rng.integers(1, 3, chosen.size)
        for i, s in enumerate(stimuli):
            for rep in range(1, counts[i] + 1):
                value = q[s.id] + bias[k] + rng.normal(0, 6)
                rows.append({"participant": f"P{k + 1:02d}", "stimulus": s.id,
                             "reference": s.reference, "repetition": rep,
                             "is_hidden_reference": s.is_hidden_reference,
                             "rating": float(np.clip(value, 0, 100))})
    return pd.DataFrame(rows)


def _first_matrix(frame: pd.DataFrame, rs: RatingSet) -> np.ndarray:
    """stimuli x raters: each rater's repetition-1 rating, straight from the tidy rows."""
    first = frame[frame["repetition"] == 1].pivot(index="stimulus", columns="participant",
                                                  values="rating")
    return first.loc[rs.stimulus_ids, rs.raters].to_numpy(dtype=float)


@pytest.fixture(scope="module")
def adaptive() -> tuple[pd.DataFrame, RatingSet]:
    loaded = _manifest()
    frame = _ratings(loaded)
    return frame, ratings_from_frame(frame, loaded)


def test_policy_comes_from_the_manifest_or_the_counts(adaptive) -> None:
    frame, rs = adaptive
    assert rs.allocation == "adaptive"
    assert rs.allocation_settings["blocks"] == 3
    assert rs.allocation_settings["max_per_block"] == 2
    full = ratings_from_frame(_ratings(_manifest("full"), extra=False), _manifest("full"))
    assert full.allocation == "full" and full.allocation_settings is None
    # An unbalanced CSV under a manifest without a policy: inferred from the counts.
    unbalanced = ratings_from_frame(frame, _manifest("full"))
    assert unbalanced.allocation == "unbalanced"
    # The same inference without any manifest (a RatingSet built directly).
    bare = RatingSet(rs.stimuli, rs.raters, rs.scores, 0.0, 100.0, 100.0)
    assert bare.allocation == "unbalanced"
    # A partial session of a full design leaves the design balanced.
    st = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=5, seed=2,
                         special={"Xpart": "partial:0.6"})
    assert ratings_from_frame(st.ratings, st.manifest).allocation == "full"


def test_icc_uses_the_block1_matrix(adaptive) -> None:
    frame, rs = adaptive
    first = _first_matrix(frame, rs)
    assert np.isfinite(first).all()
    rel = reliability(rs, n_boot=20)
    long = pd.DataFrame(first, index=rs.stimulus_ids, columns=rs.raters).stack().rename(
        "rating").rename_axis(["stimulus", "rater"]).reset_index()
    icc, ci = icc_from_long(long, "stimulus", "rater", "rating")
    assert rel.icc == pytest.approx(icc)
    assert rel.icc_ci["ICC(2,k)"] == pytest.approx(ci["ICC(2,k)"])
    assert rel.subset == f"{BLOCK1}: {len(rs.stimulus_ids)} stimuli x {N_RATERS} raters"
    inter = pd.DataFrame(first, columns=rs.raters).corr()
    np.testing.assert_allclose(rel.inter_rater.to_numpy(), inter.to_numpy())


def test_screening_uses_the_block1_matrix(adaptive) -> None:
    frame, rs = adaptive
    first = _first_matrix(frame, rs)
    result = screen_raters(rs, "grubbs")
    assert result.subset.startswith(BLOCK1)
    expected = rater_deviation(first)
    got = result.table["deviation"].reindex(rs.raters).to_numpy(dtype=float)
    np.testing.assert_allclose(got, expected)
    sub, text = balanced_subset(rs)
    np.testing.assert_array_equal(sub.scores[:, :, 0], first)
    assert text == result.subset


def test_adaptive_raters_are_complete(adaptive) -> None:
    frame, rs = adaptive
    np.testing.assert_allclose(rs.completeness(), 1.0)  # CSV: share of stimuli rated
    # A rater who stopped half-way through block 1: share of stimuli rated at least once.
    loaded = _manifest()
    half = frame[frame["participant"] == "P01"]
    keep = half["stimulus"].drop_duplicates().iloc[: half["stimulus"].nunique() // 2]
    part = pd.concat([frame[frame["participant"] != "P01"],
                      half[half["stimulus"].isin(keep)]], ignore_index=True)
    comp = ratings_from_frame(part, loaded).completeness()
    assert comp[0] == pytest.approx(len(keep) / half["stimulus"].nunique())
    np.testing.assert_allclose(comp[1:], 1.0)


def test_adaptive_sessions_are_complete(adaptive, tmp_path: Path) -> None:
    pytest.importorskip("session_store")
    frame, _ = adaptive
    manifest_path = save_manifest(_manifest().manifest, tmp_path / "manifest.json")
    sha = load_manifest(manifest_path).sha256
    for rater in ("P01", "P02", "P03"):
        rows = frame[frame["participant"] == rater]
        write_session(tmp_path / f"{rater}.sqlite", rows, study_id="adaptive-test",
                      manifest_sha256=sha)
    rs = load_ratings(manifest_path, sessions=[tmp_path])
    assert rs.allocation == "adaptive"
    planned = frame[frame["participant"].isin(["P01", "P02", "P03"])].groupby(
        "participant").size()
    np.testing.assert_array_equal(rs.rater_info.loc[rs.raters, "n_planned"].to_numpy(),
                                  planned.loc[rs.raters].to_numpy())
    np.testing.assert_allclose(rs.completeness(), 1.0)


@pytest.mark.slow  # about 7 s here: CI runs it after `make test` (.ci/run)
def test_report_states_the_policy_and_counts(adaptive) -> None:
    frame, rs = adaptive
    a = run_analysis(rs, AnalysisConfig(outliers="none", n_boot=20, n_splits=20, ci_draws=4),
                     progress=False)
    out = ARTIFACTS / "report"
    html = write_report(a, out).read_text(encoding="utf-8")
    s = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    counts = frame.groupby("stimulus").size().to_numpy()
    al = s["allocation"]
    assert al["policy"] == "adaptive" and al["settings"]["blocks"] == 3
    assert al["ratings_per_stimulus"] == {"min": int(counts.min()),
                                          "median": float(np.median(counts)),
                                          "max": int(counts.max())}
    assert s["n_ratings_used"] == len(frame)  # the score model used every rating
    n = len(rs.stimulus_ids)
    assert s["icc_subset"] == f"{BLOCK1}: {n} stimuli x {N_RATERS} raters"
    assert s["screening_subset"] == s["icc_subset"]
    assert (out / "figures" / "ratings_per_stimulus.png").stat().st_size > 5000
    assert "Allocation of ratings" in html and "ratings_per_stimulus.png" in html
    assert f"median {np.median(counts):g}" in html
    assert al["sentence"].startswith("an adaptive design (3 blocks per session")
    assert al["sentence"].endswith(f": each stimulus received {counts.min()}-{counts.max()} "
                                   f"ratings (median {np.median(counts):g})")
    assert "<p>An adaptive design (3 blocks" in html
    # the paper text gives the ICC on what it was computed on: block 1's single ratings
    text = " ".join((out / "methods.txt").read_text(encoding="utf-8").split())
    assert f"on the {BLOCK1}: {n} stimuli x {N_RATERS} raters, with 95% CIs" in text
    assert "mean over repetitions" not in text and "metrics are compared on" not in text


@pytest.mark.slow  # about 6 s here: CI runs it after `make test` (.ci/run)
def test_balanced_input_is_unchanged() -> None:
    loaded = _manifest("full", repetitions=1)
    frame = _ratings(loaded, extra=False)
    rs = ratings_from_frame(frame, loaded)
    sub, text = balanced_subset(rs)
    assert sub is rs and text == ""
    rel = reliability(rs, n_boot=20)
    assert rel.subset == "" and rel.method.startswith("pingouin")
    assert screen_raters(rs, "grubbs").subset == ""
    a = run_analysis(rs, AnalysisConfig(outliers="none", n_boot=20, n_splits=20, ci_draws=4),
                     progress=False)
    out = ARTIFACTS / "full"
    write_report(a, out)
    s = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert s["allocation"]["policy"] == "full"
    assert s["allocation"]["sentence"] == "a full design: every rater rated every stimulus once"
    assert s["icc_subset"] is None and s["screening_subset"] is None
    assert not (out / "figures" / "ratings_per_stimulus.png").exists()
