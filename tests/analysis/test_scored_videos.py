"""A scores file of other videos under the same ids (another study's, an earlier render) is
refused: joined by id alone it would give a plausible metric table for the wrong videos."""

from __future__ import annotations

import hashlib

import numpy as np
import pandas as pd
import pytest

from analysis.cli import main
from analysis.synthetic import synthetic_study
from stimuli_manifests import save_manifest


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    st = synthetic_study(n_scenes=2, methods=("blur", "noise"), levels=2, n_raters=5,
                         repetitions=1, seed=4)
    root = tmp_path_factory.mktemp("scored")
    manifest = st.manifest.manifest
    for item in [*manifest.references, *manifest.conditions]:  # as init records its videos
        item.sha256 = _sha(f"video {item.id}")
    path = save_manifest(manifest, root / "manifest.json")
    ratings = root / "ratings.csv"
    st.ratings.to_csv(ratings, index=False)
    cond = [c for c in manifest.conditions]
    rng = np.random.default_rng(0)
    table = pd.DataFrame({
        "stimulus": [str(c.id) for c in cond], "reference": [c.reference for c in cond],
        "metric": "psnr", "score": rng.normal(30, 3, len(cond)), "direction": "higher-better",
        "stimulus_sha256": [_sha(f"video {c.id}") for c in cond],
        "reference_sha256": [_sha(f"video {c.reference}") for c in cond]})
    return {"manifest": path, "ratings": ratings, "table": table, "root": root}


def _compare(files, table: pd.DataFrame, name: str) -> int:
    scores = files["root"] / f"{name}.csv"
    table.to_csv(scores, index=False)
    return main(["compare", "--manifest", str(files["manifest"]), "--ratings",
                 str(files["ratings"]), "--bootstrap", "20", "--splits", "5", "--outliers",
                 "none", "--metric", str(scores)])


def test_scores_of_this_study_s_videos_are_compared(files, capsys):
    assert _compare(files, files["table"], "same") == 0
    assert "psnr" in capsys.readouterr().out


def test_scores_of_other_videos_are_refused_in_one_line(files, capsys):
    other = files["table"].copy()
    other.loc[[1, 4], "stimulus_sha256"] = _sha("another render")
    assert _compare(files, other, "other_render") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    sid = [str(other.loc[k, "stimulus"]) for k in (1, 4)]
    assert "2 score row(s) scored other videos than" in err[0]
    assert f"{sid[0]} (stimulus_sha256 differs), {sid[1]} (stimulus_sha256 differs)" in err[0]
    assert "cgvqm batch --manifest" in err[0]


def test_a_reference_of_another_study_is_refused(files, capsys):
    other = files["table"].copy()
    other["reference_sha256"] = _sha("another study's reference")
    assert _compare(files, other, "other_reference") == 2
    err = capsys.readouterr().err
    assert f"{len(other)} score row(s)" in err and "reference_sha256 differs" in err


def test_files_that_record_no_videos_are_not_checked(files, capsys):
    """Other labs' CSVs (and ours with the sha columns emptied) give stimulus ids only."""
    bare = files["table"].drop(columns=["stimulus_sha256", "reference_sha256"])
    assert _compare(files, bare, "bare") == 0
    empty = files["table"].copy()
    empty["stimulus_sha256"] = ""
    assert _compare(files, empty, "empty") == 0


def test_swapped_inputs_name_the_option_they_belong_to(files, tmp_path, capsys):
    """A session file given to --ratings read as 'not a readable CSV ... a decimal comma?';
    a folder given to --metric said only 'Is a directory'."""
    session = tmp_path / "P01.sqlite"
    session.write_bytes(b"SQLite format 3\x00" + bytes(100))
    assert main(["compare", "--manifest", str(files["manifest"]), "--ratings", str(session),
                 "--metric", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("is a session file, not a CSV: give it (or its folder) to --sessions")
    assert main(["compare", "--manifest", str(files["manifest"]), "--ratings",
                 str(files["ratings"]), "--metric", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"--metric {tmp_path} is a folder; give the scores CSV file" in err
    assert len(err.splitlines()) == 1


def test_a_scores_file_missing_stimuli_names_them_on_stderr(files, capsys):
    """A metric's input problems are named on stderr as the ratings' are, not only counted."""
    part = files["table"].drop(index=[0, 3])
    assert _compare(files, part, "partial") == 0
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.startswith("input problem:")]
    missing = [str(files["table"].loc[i, "stimulus"]) for i in (0, 3)]
    assert any("psnr" in x and all(m in x for m in missing) for x in lines), err
