"""Metric scores as a researcher writes them for their own metric: a wrong direction, a
constant score, ids and references that do not fit the study, two files that disagree, and
files saved by spreadsheets. Each is said (or refused in one line), never turned silently
into numbers."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from analysis.cli import main
from analysis.errors import AnalysisError
from analysis.mapping import logistic5
from analysis.metric_scores import load_metric_scores
from analysis.metrics import CEILING_ROW, validate_metrics
from analysis.synthetic import synthetic_study
from stimuli_manifests import save_manifest

from .test_mixed_panel import screenshot


def _dmos(n: int = 30, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    dmos = rng.uniform(20, 100, n)
    refs = np.array(["R1", "R2", "R3"])[np.arange(n) % 3]
    return pd.DataFrame({"stimulus": [f"S{i:03d}" for i in range(n)], "reference": refs,
                         "scene": refs, "method": np.array(["blur", "noise"])[np.arange(n) % 2],
                         "level": 1, "dmos": dmos, "ci95_low": dmos - 3, "ci95_high": dmos + 3,
                         "is_hidden_reference": False})


def _csv(tmp_path, frame: pd.DataFrame, name: str = "s.csv", **kw):
    path = tmp_path / name
    frame.to_csv(path, index=False, **kw)
    return path


def _scores(d: pd.DataFrame, values, direction: str, metric: str = "mine") -> pd.DataFrame:
    return pd.DataFrame({"stimulus": d["stimulus"], "reference": d["reference"],
                         "metric": metric, "score": values, "direction": direction})


# -- a direction the wrong way round, a constant score -----------------------------------
def test_a_metric_declared_the_wrong_way_round_is_doubted(tmp_path):
    d = _dmos()
    error = 100 - d["dmos"].to_numpy()  # an error measure: lower is better
    wrong = load_metric_scores([_csv(tmp_path, _scores(d, error, "higher-better"))])
    v = validate_metrics(d, wrong, n_boot=50)
    row = v.table.set_index("metric").loc["mine"]
    # the mapping follows the data's trend, so the PLCC alone would pass for a good metric
    assert row["plcc"] > 0.99 and row["srcc"] < -0.99
    assert "mine" in v.suspect and "is it lower-better?" in v.suspect["mine"]
    assert any(p.source == "mine" and "is it lower-better?" in p.message for p in v.problems)
    right = load_metric_scores([_csv(tmp_path, _scores(d, error, "lower-better"), "ok.csv")])
    assert validate_metrics(d, right, n_boot=50).suspect == {}


def test_a_constant_metric_is_said_to_have_no_correlation(tmp_path):
    d = _dmos()
    s = load_metric_scores([_csv(tmp_path, _scores(d, 7.0, "lower-better"))])
    v = validate_metrics(d, s, n_boot=20)
    assert v.suspect["mine"] == ("it gives every stimulus the same score (7); no correlation "
                                 "is defined")


def test_problems_name_the_metric_once(tmp_path):
    d = _dmos()
    s = load_metric_scores([_csv(tmp_path, _scores(d, d["dmos"], "higher-better").iloc[:-4])])
    v = validate_metrics(d, s, n_boot=20)
    (missing,) = [p for p in v.problems if "have no score" in p.message]
    assert str(missing).startswith("mine: 4 of 30 stimuli have no score (")


# -- ids and references ----------------------------------------------------------------------
def test_a_reference_of_another_scene_is_left_out_and_a_file_stem_is_not_held_against(tmp_path):
    d = _dmos()
    s = _scores(d, d["dmos"], "higher-better")
    s.loc[0, "reference"] = "R2"  # S000's reference is R1: a scene mix-up
    s.loc[1, "reference"] = "reference_30fps"  # score --csv writes the file's stem
    v = validate_metrics(d, load_metric_scores([_csv(tmp_path, s)]), n_boot=20)
    (p,) = [p for p in v.problems if "scored against reference" in p.message]
    assert p.row == 2 and "its reference in the manifest is R1; left out" in p.message
    assert int(v.table.set_index("metric").loc["mine", "n"]) == len(d) - 1


def test_an_id_in_another_case_is_named_with_the_studys(tmp_path):
    d = _dmos()
    s = _scores(d, d["dmos"], "higher-better")
    s.loc[3, "stimulus"] = "s003"
    v = validate_metrics(d, load_metric_scores([_csv(tmp_path, s)]), n_boot=20)
    assert any("'s003' is not one of the study's rated stimuli (the study has 'S003': ids "
               "are case-sensitive)" in p.message for p in v.problems)


def test_an_empty_metric_or_stimulus_cell_is_refused_with_its_lines(tmp_path):
    d = _dmos(6)
    s = _scores(d, d["dmos"], "higher-better")
    s["metric"] = ["mine", "", "", "mine", "", "mine"]
    with pytest.raises(AnalysisError, match=r"column 'metric' is empty on line\(s\) 3-4, 6;"):
        load_metric_scores([_csv(tmp_path, s)])


def test_two_different_scores_of_one_metric_are_refused(tmp_path):
    d = _dmos(6)
    mine = _csv(tmp_path, _scores(d, d["dmos"], "lower-better", "flip"), "mine.csv")
    builtin = _csv(tmp_path, _scores(d, d["dmos"] / 100, "lower-better", "flip"), "builtin.csv")
    with pytest.raises(AnalysisError, match=r"metric 'flip' has 2 different scores for S000 "
                       r"\(.*builtin.csv:2, .*mine.csv:2\); two files hold a metric of this "
                       r"name: rename"):
        load_metric_scores([builtin, mine])
    one = _scores(d, d["dmos"], "higher-better")
    twice = pd.concat([one, one.iloc[[2]].assign(score=1.0)])
    with pytest.raises(AnalysisError, match="remove the extra row"):
        load_metric_scores([_csv(tmp_path, twice, "twice.csv")])
    same = pd.concat([one, one.iloc[[2]]])  # the same number twice: a warning, one kept
    s = load_metric_scores([_csv(tmp_path, same, "same.csv")])
    assert len(s.frame) == 6 and any("second score" in p.message for p in s.problems)


# -- files as spreadsheets save them -----------------------------------------------------
def test_semicolons_tabs_decimal_commas_and_capitals_read_as_the_plain_file(tmp_path):
    d = _dmos(8)
    plain = _scores(d, np.round(d["dmos"].to_numpy() / 7, 3), "higher-better")
    expected = load_metric_scores([_csv(tmp_path, plain)]).frame.set_index("stimulus")["score"]
    excel = plain.rename(columns={"stimulus": "Stimulus", "Score": "SCORE"})
    text = excel.to_csv(index=False, sep=";").replace(".", ",")
    (tmp_path / "excel.csv").write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode())
    _csv(tmp_path, plain, "tab.csv", sep="\t")
    for name in ("excel.csv", "tab.csv"):
        got = load_metric_scores([tmp_path / name]).frame.set_index("stimulus")["score"]
        pd.testing.assert_series_equal(got, expected)


def test_empty_and_header_only_files_are_named(tmp_path):
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(AnalysisError, match=r"empty.csv is empty: not even a header line"):
        load_metric_scores([tmp_path / "empty.csv"])
    (tmp_path / "header.csv").write_text("stimulus,reference,metric,score,direction\n")
    with pytest.raises(AnalysisError, match=r"header.csv has a header but no rows"):
        load_metric_scores([tmp_path / "header.csv"])
    (tmp_path / "u16.csv").write_bytes("stimulus,metric\n".encode("utf-16"))
    with pytest.raises(AnalysisError, match=r"u16.csv is not UTF-8 text .*save it as 'CSV UTF-8'"):
        load_metric_scores([tmp_path / "u16.csv"])


# -- the report -------------------------------------------------------------------------------
def test_the_report_warns_of_a_reversed_metric_and_its_mapping_can_be_redrawn(tmp_path):
    """A lower-better metric declared higher-better: warned on stderr, in the paper's text
    (its comparisons left out), in summary.json; and each mapping in summary.json, applied
    as its function says (with its sign), gives the table's PLCC from dmos.csv."""
    st = synthetic_study(n_scenes=3, methods=("blur", "noise"), levels=3, n_raters=8, seed=6)
    save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    st.ratings.to_csv(tmp_path / "ratings.csv", index=False)
    cond = [s for s in st.quality.index if "_" in s]
    rng = np.random.default_rng(1)
    q = st.quality[cond].to_numpy()
    frames = [(name, values, direction) for name, values, direction in (
        ("good", q + rng.normal(0, 3, len(cond)), "higher-better"),
        ("err", 100 - q + rng.normal(0, 6, len(cond)), "lower-better"),
        ("flipped", 100 - q + rng.normal(0, 3, len(cond)), "higher-better"))]
    pd.concat([pd.DataFrame({"stimulus": cond, "reference": [c.split("_")[0] for c in cond],
                             "metric": n, "score": v, "direction": dr,
                             "versions": '{"implementation":"lab 1.0"}' if n == "good" else ""})
               for n, v, dr in frames]).to_csv(tmp_path / "scores.csv", index=False)
    out = tmp_path / "out"
    rc = main(["report", "--manifest", str(tmp_path / "manifest.json"), "--ratings",
               str(tmp_path / "ratings.csv"), "--bootstrap", "40", "--splits", "20",
               "--outliers", "none", "--metric", str(tmp_path / "scores.csv"),
               "--out", str(out)])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    assert list(s["metric_doubts"]) == ["flipped"]
    text = " ".join((out / "methods.txt").read_text().split())
    assert "[Check before use: flipped: its scores fall as DMOS rises" in text
    assert "Comparisons with it are left out of this text.]" in text
    assert not any(w in text for w in ("flipped over", "over flipped"))
    assert "(z; a lower-better score negated first)" in text
    assert ("Implementations: good: lab 1.0; err and flipped: not recorded in their scores "
            "(name the implementation and version).") in text
    glance = (out / "report.html").read_text()
    assert "flipped: its scores fall as DMOS rises" in glance
    screenshot(out / "report.html", "reversed_metric_report.png", 2200)  # for a person to see
    table = pd.read_csv(out / "tables" / "metrics.csv").set_index("metric")
    assert table.index[-1] == CEILING_ROW == "two half panels (split-half agreement)"
    dmos = pd.read_csv(out / "dmos.csv").set_index("stimulus")["dmos"]
    scores = pd.read_csv(tmp_path / "scores.csv")
    for name in ("good", "err"):
        mp = s["metric_mappings"][name]
        assert mp["sign"] == (-1 if name == "err" else 1) and "sign * score" in mp["function"]
        rows = scores[scores["metric"] == name].set_index("stimulus")["score"]
        z = (mp["sign"] * rows - mp["center"]) / mp["scale"]
        predicted = logistic5(z.to_numpy(), *mp["params"])
        plcc = stats.pearsonr(predicted, dmos.reindex(rows.index).to_numpy())[0]
        assert plcc == pytest.approx(table.loc[name, "plcc"], abs=1e-9)
