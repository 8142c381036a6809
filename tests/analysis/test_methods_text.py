"""The report's "For the paper" text: every number it states is checked against a second
computation (pingouin on the kept raters, the known truth of the generated study, the
published layout of the Netflix dataset), and it says only what was computed."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pingouin as pg
import pytest

from analysis.cli import main
from analysis.methods_text import fixed, p_text, percent
from analysis.synthetic import synthetic_study
from stimuli_manifests import save_manifest

NFLX = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "sureal" / \
    "NFLX_dataset_public_raw_last4outliers.py"


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    st = synthetic_study(n_scenes=3, methods=("blur", "noise"), levels=3, n_raters=10,
                         repetitions=2, n_outliers=2, seed=6)
    root = tmp_path_factory.mktemp("methods")
    save_manifest(st.manifest.manifest, root / "manifest.json")
    st.ratings.to_csv(root / "ratings.csv", index=False)
    cond = [s for s in st.quality.index if "_" in s]
    rng = np.random.default_rng(0)
    pd.concat([pd.DataFrame({"stimulus": cond, "reference": [c.split("_")[0] for c in cond],
                             "metric": name, "score": st.quality[cond].to_numpy()
                             + rng.normal(0, sd, len(cond)), "direction": "higher-better"})
               for name, sd in (("good", 3.0), ("weak", 25.0))]).to_csv(root / "scores.csv",
                                                                      index=False)
    return st, root


def _report(root: Path, out: Path, *extra: str) -> str:
    assert main(["report", "--manifest", str(root / "manifest.json"), "--ratings",
                 str(root / "ratings.csv"), "--bootstrap", "40", "--splits", "20",
                 "--out", str(out), *extra]) == 0
    text = (out / "methods.txt").read_text()
    html = (out / "report.html").read_text()
    assert "For the paper" in html and text.split("\n")[0][:60] in html
    return " ".join(text.split())


def test_the_text_states_the_study_as_generated_and_recomputed(study, tmp_path):
    st, root = study
    out = tmp_path / "report"
    text = _report(root, out, "--metric", str(root / "scores.csv"))
    assert "Not the published metric" not in text
    n_stim = len(st.quality)
    # the design as generated: 3 scenes, 2 methods x 3 levels, one hidden reference each;
    # the manifest's default labels
    assert text.startswith(
        f"10 participants gave valid ratings. The study had {n_stim} stimuli (3 source "
        "contents; 6 distortion conditions: blur, noise at 3 levels; 18 processed sequences; "
        "3 hidden references), rated on a "
        'continuous 0 to 100 scale labelled "Very annoying" (0), "Annoying" (25), '
        '"Slightly annoying" (50), "Perceptible but not annoying" (75), "Imperceptible" (100), '
        'under the question "Rate the quality of distortions in the shown video with respect '
        'to its reference"; a full design: every rater rated every stimulus 2 times.')
    assert "mirrored" not in text
    removed = pd.read_csv(out / "tables" / "outliers.csv", dtype={"rater": str})["rater"]
    assert sorted(removed) == sorted(st.outliers)  # the two random raters, and only they
    kept = sorted(set(st.ratings["participant"]) - set(removed))
    assert f"2 raters ({', '.join(removed)}) were removed. The analysis uses {len(kept)} " \
           "raters and " \
           f"{len(kept) * n_stim * 2} ratings." in text
    assert "DMOS = Q(v) - Q(ref) + 100" in text and "40 bootstrap resamples" in text
    # ICC(2,k) (pingouin: ICC(A,k), two-way random, absolute agreement) from pingouin directly,
    # on the kept raters' mean ratings
    mean = (st.ratings[st.ratings["participant"].isin(kept)]
            .groupby(["stimulus", "participant"], as_index=False)["rating"].mean())
    icc = pg.intraclass_corr(mean, targets="stimulus", raters="participant",
                             ratings="rating").set_index("Type")
    assert f"ICC(2,k) = {icc.loc['ICC(A,k)', 'ICC']:.3f} [" in text
    assert f"over the {len(kept)} raters used" in text
    # each metric's PLCC and SRCC as in the metric table; the ceiling only once
    table = pd.read_csv(out / "tables" / "metrics.csv").set_index("metric")
    for name in ("good", "weak"):
        assert f"{name}: PLCC {table.loc[name, 'plcc']:.3f} [" in text
        assert f"SRCC {table.loc[name, 'srcc']:.3f} [" in text
        assert f"RMSE {table.loc[name, 'rmse']:.2f} [" in text
    assert "two half panels (split-half agreement): PLCC" not in text  # its own sentence
    assert re.search(r"good over weak \(p [=<≤] [0-9.e-]+\)", text)
    assert "weak over good" not in text and "each pair on the stimuli" not in text
    # the ICC on the distorted stimuli alone, from pingouin directly
    dist = mean[mean["stimulus"].str.contains("_")]
    icc_d = pg.intraclass_corr(dist, targets="stimulus", raters="participant",
                               ratings="rating").set_index("Type")
    assert f"On the {n_stim - 3} distorted stimuli alone, the ones the metrics are compared " \
           f"on, ICC(2,k) = {icc_d.loc['ICC(A,k)', 'ICC']:.3f} [" in text
    assert f"and ICC(2,1) = {icc_d.loc['ICC(A,1)', 'ICC']:.3f} [" in text
    # the ICC's targets include the hidden references, and the text says so
    assert f"over the {len(kept)} raters used and {n_stim} stimuli (3 hidden references " \
           "among them)" in text
    # the ceiling a metric faces: Spearman-Brown of the median split-half PLCC (8 raters: two
    # halves of 4, k = 2), and its square root
    half = pd.read_csv(out / "tables" / "ceiling.csv", index_col=0)
    r = float(half.loc["plcc", "median"]) if "plcc" in half.index else None
    assert r is not None
    sb = 2 * r / (1 + r)
    assert f"reliability is {sb:.3f}; a metric that predicted the true quality exactly would " \
           f"reach a PLCC of about {np.sqrt(sb):.3f}" in text


def test_without_screening_or_metrics_it_says_so_and_no_more(study, tmp_path):
    _, root = study
    text = _report(root, tmp_path / "plain", "--outliers", "none")
    assert "No rater screening was applied." in text and "removed" not in text
    assert "Each metric" not in text and "bootstrap of the PLCC" not in text


@pytest.mark.slow
@pytest.mark.skipif(not NFLX.is_file(), reason="shared NFLX data absent")
def test_the_netflix_dataset_reads_as_published(tmp_path):
    """NFLX public: 26 raters and 79 stimuli (70 distorted, 9 references), every stimulus
    rated once by every rater; this variant adds 4 random raters, which the screening finds."""
    assert main(["report", "--sureal", str(NFLX), "--bootstrap", "50", "--splits", "20",
                 "--out", str(tmp_path / "nflx")]) == 0
    text = " ".join((tmp_path / "nflx" / "methods.txt").read_text().split())
    assert text.startswith("30 participants gave valid ratings. The study had 79 stimuli (9 "
                           "source contents; 70 distorted versions; 9 hidden references), "
                           "rated on a 1 to 5 scale; a full design: every rater rated every "
                           "stimulus once.")
    # NFLX labels no HRC, so P.913's r2 cannot run, and the text says so
    assert "r1 decided alone" in text and "r2 < 0.8" not in text
    assert re.search(r"4 raters \((2[6-9], ){3}2[6-9]\) were removed\. [^.]*\. The analysis "
                     r"uses 26 raters and 2054 ratings\.", text)
    assert "2 raters close to the rule were kept (2, 6)" in text  # the report's near-misses
    assert "DMOS = Q(v) - Q(ref) + 5" in text


def _ratings(root: Path) -> pd.DataFrame:
    return pd.read_csv(root / "ratings.csv", dtype={"participant": str})


@pytest.mark.slow  # about 15 s here: CI runs it after `make test` (.ci/run)
def test_an_impairment_scale_is_said_to_be_mirrored_and_changes_no_number(study, tmp_path):
    """The same study on a lower-is-better scale (ratings 100 - r): the text says how the
    participants rated and that the numbers are on the mirrored scale; every number stays."""
    _, root = study
    manifest = json.loads((root / "manifest.json").read_text())
    manifest["scale"] = {"min": 0, "max": 100, "direction": "lower_is_better",
                         "labels": [{"position": 0, "text": "Imperceptible"},
                                    {"position": 100, "text": "Very annoying"}],
                         "question": "How annoying are the differences from the reference?"}
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    flipped = _ratings(root)
    flipped["rating"] = 100 - flipped["rating"]
    flipped.to_csv(tmp_path / "ratings.csv", index=False)
    text = _report(tmp_path, tmp_path / "lib")
    same = _report(root, tmp_path / "hib")
    assert ('on a continuous 0 to 100 scale, on which lower meant better, labelled '
            '"Imperceptible" (0), "Very annoying" (100), under the question "How annoying '
            'are the differences from the reference?"') in text
    assert "every rating x was mirrored to 0 + 100 - x" in text and "mirrored" not in same
    icc = re.search(r"ICC\(2,k\) = [0-9.]+ \[[0-9., ]+\]", same)
    assert icc and icc.group(0) in text
    summary = json.loads((tmp_path / "lib" / "summary.json").read_text())
    assert summary["scale"]["mirrored"] is True and summary["scale"]["direction"] == \
        "lower_is_better"
    assert summary["scale"]["question"] == "How annoying are the differences from the " \
        "reference?"


def test_without_hidden_references_no_dmos_is_claimed(study, tmp_path):
    """No hidden reference rated: the scores are quality estimates, and the text, the methods
    table and dmos.csv agree (dmos equals quality)."""
    _, root = study
    ratings = _ratings(root)
    ratings[~ratings["is_hidden_reference"]].to_csv(tmp_path / "ratings.csv", index=False)
    (tmp_path / "manifest.json").write_text((root / "manifest.json").read_text())
    text = _report(tmp_path, tmp_path / "noref", "--outliers", "none")
    dmos = pd.read_csv(tmp_path / "noref" / "dmos.csv")
    assert (dmos["dmos"] - dmos["quality"]).abs().max() == 0
    assert "no DMOS was formed" in text and "Q(ref)" not in text
    assert "no hidden reference)" in text  # the design counts none
    html = (tmp_path / "noref" / "report.html").read_text()
    assert "not formed: no hidden reference was rated" in html


@pytest.mark.slow  # about 11 s here: CI runs it after `make test` (.ci/run)
def test_each_metric_is_given_its_own_stimuli_and_pairs_their_shared_ones(study, tmp_path):
    """A metric scored on fewer stimuli: its count in the text is the metric table's, and a
    significant difference involving it names the stimuli both metrics scored."""
    _, root = study
    scores = pd.read_csv(root / "scores.csv")
    weak = scores[scores["metric"] == "weak"]
    drop = weak["stimulus"].iloc[:5]
    fewer = scores.drop(index=drop.index)
    fewer.to_csv(tmp_path / "scores.csv", index=False)
    text = _report(root, tmp_path / "few", "--metric", str(tmp_path / "scores.csv"))
    table = pd.read_csv(tmp_path / "few" / "tables" / "metrics.csv").set_index("metric")
    n_all, n_weak = int(table.loc["good", "n"]), int(table.loc["weak", "n"])
    assert n_weak == n_all - 5
    assert f"on up to {n_all} distorted stimuli" in text
    assert f"weak ({n_weak} of the {n_all} stimuli scored): PLCC " \
           f"{table.loc['weak', 'plcc']:.3f}" in text
    assert "each pair on the stimuli both metrics scored" in text
    if "good over weak" in text:
        assert f"on the {n_weak} stimuli both scored" in text


def test_raters_the_bt500_model_rejects_are_left_out_of_every_number(study, tmp_path):
    """--model bt500 rejects raters inside the model: they count as removals in the text and
    summary, and the ICC is pingouin's on the raters the scores used."""
    st, root = study
    out = tmp_path / "bt500"
    text = _report(root, out, "--model", "bt500", "--outliers", "none")
    summary = json.loads((out / "summary.json").read_text())
    rejected = summary["model_rejected_raters"]
    assert sorted(rejected) == sorted(st.outliers)  # BT.500 finds the two random raters
    kept = sorted(set(st.ratings["participant"]) - set(rejected))
    assert summary["n_raters_used"] == len(kept)
    assert f"removed {len(rejected)} rater" in text and f"uses {len(kept)} raters" in text
    mean = (st.ratings[st.ratings["participant"].isin(kept)]
            .groupby(["stimulus", "participant"], as_index=False)["rating"].mean())
    icc = pg.intraclass_corr(mean, targets="stimulus", raters="participant",
                             ratings="rating").set_index("Type")
    assert summary["icc"]["ICC(2,k)"] == pytest.approx(icc.loc["ICC(A,k)", "ICC"], abs=1e-9)
    quality = pd.read_csv(out / "tables" / "data_quality.csv", dtype={"rater": str})
    status = quality.set_index("rater")["status"]
    assert all(status[r] == "removed (--model bt500)" for r in rejected)
    assert "rejected by the score model" in (out / "report.html").read_text()


@pytest.mark.slow  # about 6 s here: CI runs it after `make test` (.ci/run)
def test_with_fewer_than_four_hrcs_the_p913_rule_is_r1_alone(tmp_path):
    """Three HRCs (two levels and the hidden reference): P.913's r2 cannot be computed,
    and the text does not claim it."""
    st = synthetic_study(n_scenes=5, methods=("blur",), levels=2, n_raters=8,
                         repetitions=1, n_outliers=1, seed=3)
    save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    st.ratings.to_csv(tmp_path / "ratings.csv", index=False)
    text = _report(tmp_path, tmp_path / "r1")
    assert "r1 decided alone" in text and "r1 < 0.75 and r2 < 0.8" not in text
    assert "needs 4 HRCs and was not computed" in (tmp_path / "r1" / "report.html").read_text()


def test_numbers_are_printed_as_a_paper_prints_them():
    assert p_text(1 / 1001) == "p < 0.001" and p_text(0.001) == "p = 0.001"
    assert p_text(0.0366) == "p = 0.037"
    # the floor of a bootstrap p (no resample contradicted) is a bound, worded one way
    assert p_text(1 / 1000, 999) == p_text(1 / 1001, 1000) == "p ≤ 0.001"
    assert p_text(1 / 41, 40) == "p ≤ 0.025" and p_text(2 / 41, 40) == "p = 0.049"
    assert percent(0.995) == "99.5%" and percent(0.83) == "83%" and percent(1.0) == "100%"
    assert percent(0.004) == "0.4%"
    assert fixed(-0.0001) == "0.000" and fixed(-0.01) == "-0.010"


def test_a_reader_can_redraw_each_mapping_and_name_each_implementation(study, tmp_path):
    """The fitted mapping, the metric's implementation and the analysis' libraries were
    nowhere in the report: a reviewer could not recompute PLCC or RMSE from the files. And
    the first screen flagged a random backbone, the text meant for the paper did not."""
    import json

    _, root = study
    scores = pd.read_csv(root / "scores.csv")
    scores["versions"] = '{"implementation":"labmetric 2.1"}'
    scores["settings"] = '{"frames":"mean"}'
    scores["backbone"] = np.where(scores["metric"] == "weak", "random(seed=0)", "")
    scores.to_csv(tmp_path / "scores.csv", index=False)
    out = tmp_path / "prov"
    text = _report(root, out, "--outliers", "none", "--metric", str(tmp_path / "scores.csv"))
    assert ("[Not the published metric: weak ran with random (untrained) backbone: "
            "random(seed=0). Its numbers here are not those of the metric it is named "
            "after.]") in text
    assert "good ran with" not in text  # (and no such line without flags: the first test)
    assert "Implementations: good and weak: labmetric 2.1." in text
    assert "The mapping was DMOS = b1 (1/2 - 1/(1 + exp(b2 (z - b3)))) + b4 z + b5" in text
    s = json.loads((out / "summary.json").read_text())
    assert s["metric_provenance"]["good"] == {"versions": [{"implementation": "labmetric 2.1"}],
                                             "settings": [{"frames": "mean"}]}
    env = s["inputs"]["environment"]
    assert env["sureal"] and env["numpy"] == np.__version__
    # PLCC recomputed from the raw scores, the published mapping and dmos.csv
    dmos = pd.read_csv(out / "dmos.csv").set_index("stimulus")["dmos"]
    table = pd.read_csv(out / "tables" / "metrics.csv").set_index("metric")
    for name in ("good", "weak"):
        mp = s["metric_mappings"][name]
        assert mp["kind"] == "logistic5"
        rows = scores[scores["metric"] == name].set_index("stimulus")
        z = (rows["score"] - mp["center"]) / mp["scale"]
        b1, b2, b3, b4, b5 = mp["params"]
        pred = b1 * (0.5 - 1 / (1 + np.exp(b2 * (z - b3)))) + b4 * z + b5
        r = np.corrcoef(pred, dmos.reindex(rows.index))[0, 1]
        assert r == pytest.approx(table.loc[name, "plcc"], abs=1e-9)
