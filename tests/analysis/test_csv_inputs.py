"""Ratings CSVs (``--ratings``) held to the rules session files are held to: another study's
rows are refused, duplicates go to the earlier session whatever the order of files and rows,
and a zip or damaged archive given by mistake gives one line. A stray zip in a sessions folder
is noted, not fatal; a withdrawn session is not exported as a CSV."""

from __future__ import annotations

import gzip
import zipfile
from pathlib import Path

import pandas as pd
import pytest

from analysis.cli import main as analyze
from analysis.inputs import load_ratings
from analysis.synthetic import synthetic_study
from cgvq_cli.study_cli import main as study
from session_store import read_session, write_ratings_csv
from stimuli_manifests import load_manifest, save_manifest

from .conftest import write_session


def _trials(manifest) -> list[tuple[str, str, int, bool]]:
    return [(s.id, s.reference, rep, s.is_hidden_reference)
            for rep in range(1, manifest.protocol.repetitions + 1) for s in manifest.stimuli()]


def _panel(root: Path, study_id: str = "synthetic", n_raters: int = 4, seed: int = 8):
    st = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=n_raters,
                         repetitions=1, noise_sd=4, seed=seed, study_id=study_id)
    root.mkdir(parents=True)
    mpath = save_manifest(st.manifest.manifest, root / "manifest.json")
    sha = load_manifest(mpath).sha256
    folder = root / "sessions"
    folder.mkdir()
    for rater, rows in st.ratings.groupby("participant"):
        write_session(folder / f"{rater}.sqlite", rows, study_id=study_id,
                      manifest_sha256=sha, all_trials=_trials(st.manifest.manifest))
    return st, mpath, sha, folder


def _csv(session: Path, out: Path, **changes) -> Path:
    rows = [{**r, **changes} for r in read_session(session).ratings]
    return write_ratings_csv(rows, out)


def _used(rs, rater: str, stimulus: str) -> float:
    return float(rs.scores[rs.stimulus_ids.index(stimulus), rs.raters.index(rater), 0])


def test_a_csv_of_another_study_is_refused_like_its_session_file(tmp_path):
    st, mpath, _, folder = _panel(tmp_path / "a")
    _, _, _, other = _panel(tmp_path / "b", study_id="other-study", n_raters=2, seed=99)
    mine = [_csv(f, tmp_path / f"mine_{f.stem}.csv") for f in sorted(folder.glob("*.sqlite"))]
    # The other study's P01 listed first: its ratings used to replace this study's P01's.
    theirs = _csv(other / "P01.sqlite", tmp_path / "theirs_P01.csv")
    rs = load_ratings(mpath, ratings_csv=[theirs, *mine])
    assert rs.raters == ["P01", "P02", "P03", "P04"]
    [refused] = [x for x in rs.exclusions if x.kind == "refused session"]
    assert "theirs_P01.csv" in refused.who and "'other-study'" in refused.reason
    truth = st.ratings[st.ratings.participant == "P01"].iloc[0]
    assert _used(rs, "P01", truth.stimulus) == pytest.approx(truth.rating)
    assert not any("duplicate" in p.message for p in rs.problems)
    with pytest.raises(Exception, match="no ratings of this study"):
        load_ratings(mpath, ratings_csv=[theirs])


def test_csv_duplicates_go_to_the_earlier_session_whatever_the_order(tmp_path):
    st, mpath, sha, folder = _panel(tmp_path / "a")
    p04 = st.ratings[st.ratings.participant == "P04"]
    later = write_session(tmp_path / "P04_later.sqlite", p04.head(3).assign(rating=1.0),
                          study_id="synthetic", manifest_sha256=sha, session_id="p04-later")
    first = _csv(folder / "P04.sqlite", tmp_path / "P04_first.csv",
                 presented_at="2026-01-01T00:00:00Z")
    second = _csv(later, tmp_path / "P04_later.csv", presented_at="2026-01-02T00:00:00Z")
    rest = [_csv(f, tmp_path / f"{f.stem}.csv") for f in sorted(folder.glob("P0[123].sqlite"))]
    stimulus = p04.iloc[0].stimulus
    for order in ([first, second], [second, first]):
        rs = load_ratings(mpath, ratings_csv=[*order, *rest])
        assert _used(rs, "P04", stimulus) == pytest.approx(p04.iloc[0].rating)
        dups = [p for p in rs.problems if "duplicate rating" in p.message]
        assert len(dups) == 3 and all("P04_later.csv" in p.source for p in dups)
        assert all("earlier session (" + str(first) + ")" in p.message for p in dups)
    # One CSV with the later session's rows first: the same choice.
    both = tmp_path / "both.csv"
    pd.concat([pd.read_csv(second), pd.read_csv(first)]).to_csv(both, index=False)
    rs = load_ratings(mpath, ratings_csv=[both, *rest])
    assert _used(rs, "P04", stimulus) == pytest.approx(p04.iloc[0].rating)


def test_csv_duplicates_without_times_name_the_row_read_first(tmp_path):
    _, mpath, _, _ = _panel(tmp_path / "a")
    plain = pd.DataFrame({"participant": ["P01", "P01"], "stimulus": ["SRC01", "SRC01"],
                          "repetition": [1, 1], "rating": [90.0, 40.0]})
    plain.to_csv(tmp_path / "plain.csv", index=False)
    rs = load_ratings(mpath, ratings_csv=[tmp_path / "plain.csv"])
    [dup] = [p for p in rs.problems if "duplicate" in p.message]
    assert "row read first" in dup.message and "earlier session" not in dup.message


def test_archives_and_folders_given_as_ratings_give_one_line(tmp_path, capsys):
    _, mpath, _, folder = _panel(tmp_path / "a")
    export = tmp_path / "P01.zip"
    assert study(["export", str(folder / "P01.sqlite"), "--out", str(export)]) == 0
    good = _csv(folder / "P01.sqlite", tmp_path / "P01.csv")
    cut = tmp_path / "cut.csv.gz"
    data = gzip.compress(good.read_bytes())
    cut.write_bytes(data[: len(data) // 2])
    capsys.readouterr()
    for given, says in ((export, "give it to --sessions"), (cut, "not a readable CSV"),
                        (folder, "is a folder")):
        code = analyze(["dmos", "--manifest", str(mpath), "--model", "mos", "--ratings",
                        str(given), "--out", str(tmp_path / "d.csv")])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and says in err[0], err


def test_a_stray_zip_in_a_sessions_folder_is_noted_not_fatal(tmp_path):
    _, mpath, _, folder = _panel(tmp_path / "a")
    with zipfile.ZipFile(folder / "P03_screenshots.zip", "w") as zf:
        zf.writestr("notes.txt", "my screen was too bright")
    rs = load_ratings(mpath, sessions=[folder])
    assert rs.raters == ["P01", "P02", "P03", "P04"]
    assert any("P03_screenshots.zip" in p.source and "holds no session file" in p.message
               for p in rs.problems)
    with pytest.raises(Exception, match="no session files"):  # named itself: still an error
        load_ratings(mpath, sessions=[folder / "P03_screenshots.zip"])


def test_a_withdrawn_session_is_not_exported_as_a_csv(tmp_path, capsys):
    st, _, sha, _ = _panel(tmp_path / "a")
    gone = write_session(tmp_path / "P05.sqlite", st.ratings[st.ratings.participant == "P01"]
                         .assign(participant="P05"), study_id="synthetic",
                         manifest_sha256=sha, withdraw=True)
    capsys.readouterr()
    code = study(["export", str(gone), "--out", str(tmp_path / "z"), "--csv",
                  str(tmp_path / "P05.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "withdrew" in err[0]
    assert not (tmp_path / "P05.csv").exists()
    assert study(["export", str(gone), "--out", str(tmp_path / "z")]) == 0  # the zip: as is


def test_a_csv_of_an_earlier_manifest_version_is_refused(tmp_path):
    """After ``serve --new-version`` the CSV rows say which manifest they ran on (1.1)."""
    _, mpath, _, folder = _panel(tmp_path / "a")
    mine = [_csv(f, tmp_path / f"{f.stem}.csv") for f in sorted(folder.glob("P0[123].sqlite"))]
    old = _csv(folder / "P04.sqlite", tmp_path / "P04_old.csv", manifest_sha256="0" * 64)
    rs = load_ratings(mpath, ratings_csv=[*mine, old])
    assert rs.raters == ["P01", "P02", "P03"]
    [refused] = [x for x in rs.exclusions if x.kind == "refused session"]
    assert "P04_old.csv" in refused.who and "manifest.000000000000.json" in refused.reason
    # rows without the column (tables before 1.1) are kept
    pd.read_csv(old).drop(columns=["manifest_sha256"]).to_csv(old, index=False)
    assert load_ratings(mpath, ratings_csv=[*mine, old]).raters == ["P01", "P02", "P03", "P04"]
