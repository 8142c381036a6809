"""A reviewer re-runs the analysis on a copy of the supplementary material: another folder,
another working folder, relative paths. Every number was the same, yet the tables and
summary.json differed (the session files' paths as given, the timings), so a byte comparison
flagged files that hold identical results."""

from __future__ import annotations

import json
import shutil

import pandas as pd
from support.cli import analyze
from support.sessions import blur_manifest, player_session

from stimuli_manifests import load_manifest

RUN_SPECIFIC = ("inputs", "run")  # where the files lay, the command line, the timings


def _study(folder):
    return blur_manifest(folder, "copied")


def _outputs(folder):
    return {p.relative_to(folder).as_posix(): p for p in sorted(folder.rglob("*"))
            if p.suffix in (".csv", ".txt", ".json")}


def test_a_copy_elsewhere_run_from_elsewhere_gives_the_same_files(tmp_path, capsys,
                                                                  monkeypatch):
    authors = tmp_path / "authors"
    sessions = authors / "pulled"
    (sessions / "batch2").mkdir(parents=True)
    loaded = load_manifest(_study(authors))
    for k, p in enumerate(("P1", "P2", "P3", "P4", "P5")):
        player_session(sessions / ("batch2" if p in ("P4", "P5") else ""), loaded, p,
                       seed=k + 1)
    # the reviewer's copy: other names, deeper, run from a folder beside it
    review = tmp_path / "review"
    shutil.copytree(sessions, review / "supp" / "sessions")
    shutil.copy(authors / "manifest.json", review / "supp" / "study.json")
    (review / "work" / "sub").mkdir(parents=True)

    options = ("--model", "mos", "--outliers", "none", "--bootstrap", "20", "--splits", "20")
    monkeypatch.chdir(authors)
    code, _, err = analyze(capsys, "report", "--manifest", "manifest.json", "--sessions",
                           "pulled/", *options, "--out", "report")
    assert code == 0, err
    monkeypatch.chdir(review / "work" / "sub")
    code, _, err = analyze(capsys, "report", "--manifest", "../../supp/study.json",
                           "--sessions", "../../supp/sessions", *options, "--out", "../rep")
    assert code == 0, err

    first, second = _outputs(authors / "report"), _outputs(review / "work" / "rep")
    assert set(first) == set(second) and "tables/data_quality.csv" in first
    for name, path in first.items():
        if name == "summary.json":
            a, b = json.loads(path.read_text()), json.loads(second[name].read_text())
            assert a["inputs"] != b["inputs"]  # the paths differ, and only there
            for key in RUN_SPECIFIC:
                a.pop(key), b.pop(key)
            assert a == b
        else:
            assert path.read_bytes() == second[name].read_bytes(), name
    # a file is named by its path inside the folder given
    files = pd.read_csv(authors / "report" / "tables" / "data_quality.csv",
                        index_col="rater")["files"]
    assert files.to_dict() == {"P1": "P1.sqlite", "P2": "P2.sqlite", "P3": "P3.sqlite",
                               "P4": "batch2/P4.sqlite", "P5": "batch2/P5.sqlite"}


def test_a_session_file_given_by_itself_is_named_by_its_file_name(tmp_path, capsys):
    loaded = load_manifest(path := _study(tmp_path))
    for k in range(4):
        (tmp_path / f"d{k}").mkdir()
    given = [player_session(tmp_path / f"d{k}", loaded, p, seed=k + 1)
             for k, p in enumerate(("P1", "P2", "P3", "P4"))]
    out = tmp_path / "r"
    code, _, err = analyze(capsys, "report", "--manifest", path, "--sessions", *given,
                           "--model", "mos", "--outliers", "none", "--bootstrap", "20",
                           "--splits", "20", "--out", out)
    assert code == 0, err
    files = pd.read_csv(out / "tables" / "data_quality.csv", index_col="rater")["files"]
    assert sorted(files) == [f"{p}.sqlite" for p in ("P1", "P2", "P3", "P4")]
    summary = json.loads((out / "summary.json").read_text())
    assert "source" not in summary and "timings_s" not in summary
    assert set(summary["run"]["timings_s"]) >= {"scores", "reliability"}
    assert summary["inputs"]["sessions"][0]["path"] == str(given[0].resolve())
