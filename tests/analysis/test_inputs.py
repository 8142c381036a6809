"""Malformed ratings are reported per row and left out; session files are read and checked."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.errors import AnalysisError
from analysis.inputs import load_ratings, ratings_from_frame
from analysis.synthetic import synthetic_manifest, synthetic_study
from stimuli_manifests import save_manifest


def _small():
    return synthetic_study(n_scenes=2, methods=("blur",), levels=2, n_raters=4, repetitions=2,
                           noise_sd=3, seed=1)


def test_bad_csv_rows_are_reported_and_left_out(tmp_path: Path) -> None:
    st = _small()
    frame = st.ratings.copy()
    good_count = len(frame)
    extra = [
        {**frame.iloc[0].to_dict(), "rating": np.nan},             # missing rating
        {**frame.iloc[0].to_dict(), "rating": 140.0, "repetition": 7},  # out of range
        {**frame.iloc[0].to_dict(), "stimulus": "SRC99_HRC01"},     # unknown stimulus
        {**frame.iloc[1].to_dict()},                                # duplicate
        {**frame.iloc[0].to_dict(), "reference": "SRC02", "repetition": 8},  # wrong reference
        {**frame.iloc[0].to_dict(), "rating": "abc", "repetition": 9},      # not a number
    ]
    frame = pd.concat([frame, pd.DataFrame(extra)], ignore_index=True)
    csv = tmp_path / "ratings.csv"
    frame.to_csv(csv, index=False)
    manifest = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    rs = load_ratings(manifest, ratings_csv=csv)
    assert rs.n_ratings == good_count
    lines = {p.row: p.message for p in rs.problems if p.row is not None}
    first = good_count + 2  # CSV line of the first bad row (header is line 1)
    assert "missing or not a number" in lines[first]
    assert "outside the scale" in lines[first + 1]
    assert "not in the manifest" in lines[first + 2]
    assert "duplicate" in lines[first + 3]
    assert "contradicts the manifest" in lines[first + 4]
    assert "missing or not a number" in lines[first + 5]
    assert all(p.source == str(csv) for p in rs.problems if p.row is not None)
    # the good ratings are intact
    m = st.ratings.groupby(["stimulus"])["rating"].mean()
    ours = np.nanmean(rs.scores.reshape(rs.n_stimuli, -1), axis=1)
    np.testing.assert_allclose(ours, m[rs.stimulus_ids].to_numpy())


def test_csv_errors(tmp_path: Path) -> None:
    st = _small()
    manifest = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    bad = tmp_path / "bad.csv"
    bad.write_text("participant,stimulus\nP1,SRC01\n")
    with pytest.raises(AnalysisError, match="lacks column"):
        load_ratings(manifest, ratings_csv=bad)
    with pytest.raises(AnalysisError, match="does not exist"):
        load_ratings(manifest, ratings_csv=tmp_path / "none.csv")
    junk = tmp_path / "junk.csv"
    junk.write_text("participant,stimulus,rating\nP1,NOPE,10\n")
    with pytest.raises(AnalysisError, match="no valid ratings"):
        load_ratings(manifest, ratings_csv=junk)
    with pytest.raises(AnalysisError, match="not both or neither"):
        load_ratings(manifest)


def test_a_header_only_csv_says_the_table_has_no_rows(tmp_path: Path) -> None:
    st = _small()
    manifest = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    header = tmp_path / "header.csv"
    st.ratings.head(0).to_csv(header, index=False)
    with pytest.raises(AnalysisError, match=r"ratings table .*header\.csv has no rows") as err:
        load_ratings(manifest, ratings_csv=header)
    assert "first problems" not in str(err.value)


def test_nan_ratings_are_shown_as_plain_numbers(tmp_path: Path) -> None:
    st = _small()
    manifest = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    csv = tmp_path / "nan.csv"
    st.ratings.head(3).assign(rating=[np.nan, np.inf, np.nan]).to_csv(csv, index=False)
    with pytest.raises(AnalysisError, match="no valid ratings left") as err:
        load_ratings(manifest, ratings_csv=csv)
    text = str(err.value)
    assert "np.float64" not in text and "rating (empty) is missing or not a number" in text
    assert "rating 'inf' is missing" in text  # CSV cells are read as the text they hold
    words = tmp_path / "words.csv"
    st.ratings.head(1).assign(rating=["abc"]).to_csv(words, index=False)
    with pytest.raises(AnalysisError, match="rating 'abc' is missing or not a number"):
        load_ratings(manifest, ratings_csv=words)


def test_lower_is_better_scale_is_mirrored() -> None:
    st = _small()
    m = st.manifest.manifest.model_copy(deep=True)
    m.scale.direction = "lower_is_better"
    from stimuli_manifests import LoadedManifest

    rs = ratings_from_frame(st.ratings, LoadedManifest(m, None, Path(".")))
    first = st.ratings.iloc[0]
    e = rs.stimulus_ids.index(first["stimulus"])
    s = rs.raters.index(first["participant"])
    assert rs.scores[e, s, 0] == pytest.approx(100.0 - first["rating"])


def test_repetition_column_optional() -> None:
    st = _small()
    frame = st.ratings.drop(columns=["repetition", "reference"])
    rs = ratings_from_frame(frame, st.manifest)
    assert rs.n_repetitions == 2 and rs.n_ratings == len(frame) and not rs.problems


# -- session files ---------------------------------------------------------------------------
session = pytest.importorskip("session_store")
needs_writer = pytest.mark.skipif(
    not all(hasattr(session, n) for n in ("SessionStore", "PlannedTrial", "TrialResult",
                                           "read_ratings")),
    reason="session_store lacks the agreed writer/reader API")


def _write_session(path: Path, participant: str, votes: dict[tuple[str, int], float],
                   manifest) -> None:
    stimuli = {s.id: s for s in manifest.stimuli()}
    plan = [session.PlannedTrial(index=i, stimulus=sid, reference=stimuli[sid].reference,
                                 repetition=rep, is_hidden_reference=stimuli[sid]
                                 .is_hidden_reference)
            for i, (sid, rep) in enumerate(votes)]
    store = session.SessionStore.create(path, participant=participant, study_id="synthetic",
                                        manifest_sha256=None, seed=1, app_version="test",
                                        plan=plan)
    try:
        for i, value in enumerate(votes.values()):
            store.record(i, session.TrialResult(rating=value, rt_ms=1000.0, n_toggles=1,
                                                ms_on_reference=500.0, ms_on_test=500.0,
                                                presented_at="2026-01-01T00:00:00Z"))
    finally:
        store.close()


@needs_writer
def test_session_files_with_a_broken_chain(tmp_path: Path) -> None:
    manifest = synthetic_manifest(n_scenes=2, methods=("blur",), levels=2, repetitions=1)
    mpath = save_manifest(manifest, tmp_path / "manifest.json")
    ids = [s.id for s in manifest.stimuli()]
    rng = np.random.default_rng(0)
    truth = {}
    folder = tmp_path / "sessions"
    for p in ("P1", "P2", "P3"):
        votes = {(sid, 1): float(rng.uniform(0, 100)) for sid in ids}
        truth[p] = votes
        _write_session(folder / f"{p}.sqlite", p, votes, manifest)
    # Edit one stored rating of P2 (trial 2) behind the app's back.
    with sqlite3.connect(folder / "P2.sqlite") as con:
        con.execute("UPDATE ratings SET rating = 99.5 WHERE trial = 2")
    (folder / "notes.sqlite").write_bytes(b"not a database at all")
    rs = load_ratings(mpath, sessions=[folder])
    assert rs.raters == ["P1", "P2", "P3"]
    broken = [p for p in rs.problems if "hash chain" in p.message]
    assert len(broken) == 1 and broken[0].row == 2 and "P2.sqlite" in broken[0].source
    assert any("notes.sqlite" in p.source for p in rs.problems)
    p2 = rs.raters.index("P2")
    # P2's trials 0 and 1 are kept, trial 2 on are left out
    assert np.isfinite(rs.scores[:, p2, 0]).sum() == 2
    for (sid, _), value in truth["P1"].items():
        assert rs.scores[rs.stimulus_ids.index(sid), 0, 0] == pytest.approx(value)
    # files can also be given one by one
    one = load_ratings(mpath, sessions=[folder / "P1.sqlite", folder / "P3.sqlite"])
    assert one.raters == ["P1", "P3"]
    # sessions written without the manifest checksum are used, with a note saying so
    assert all("no manifest checksum" in p.message for p in one.problems)


@needs_writer
def test_session_folder_errors(tmp_path: Path) -> None:
    manifest = synthetic_manifest(n_scenes=1, levels=1)
    mpath = save_manifest(manifest, tmp_path / "manifest.json")
    (tmp_path / "empty").mkdir()
    with pytest.raises(AnalysisError, match="no session files"):
        load_ratings(mpath, sessions=[tmp_path / "empty"])
    with pytest.raises(AnalysisError, match="does not exist"):
        load_ratings(mpath, sessions=[tmp_path / "nope"])
