"""Ratings from another lab, as spreadsheets write them: each file gives the ratings of the
plain tidy CSV it was made from, or one line saying what to change; never a traceback or a
quietly different number."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.cli import main as analyze
from analysis.data import rater_order
from analysis.errors import AnalysisError
from analysis.inputs import load_ratings
from analysis.quality import facts_from_rows
from analysis.synthetic import synthetic_study
from stimuli_manifests import save_manifest

COLUMNS = ["participant", "stimulus", "rating"]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    st = synthetic_study(n_scenes=2, methods=("blur",), levels=2, n_raters=4, repetitions=1,
                         noise_sd=3, seed=1)
    folder = tmp_path_factory.mktemp("other-lab")
    manifest = save_manifest(st.manifest.manifest, folder / "manifest.json")
    plain = folder / "plain.csv"
    ratings = st.ratings[COLUMNS].assign(rating=st.ratings["rating"].round(1))
    ratings.to_csv(plain, index=False)
    return manifest, plain, ratings, load_ratings(manifest, ratings_csv=plain)


def same(a, b) -> bool:
    return a.raters == b.raters and np.array_equal(a.scores, b.scores, equal_nan=True)


def test_an_excel_file_from_a_comma_decimal_locale_reads_as_the_plain_one(study, tmp_path):
    manifest, _, ratings, baseline = study
    excel = tmp_path / "excel.csv"
    with open(excel, "w", encoding="utf-8-sig", newline="") as fh:  # BOM, CRLF, ';', '2,5'
        ratings.rename(columns=str.capitalize).to_csv(fh, sep=";", decimal=",", index=False,
                                                     lineterminator="\r\n")
        fh.write(";;\r\n;;\r\n")  # the empty rows Excel leaves below a table
    assert "," in excel.read_text(encoding="utf-8-sig")  # decimal commas were written
    rs = load_ratings(manifest, ratings_csv=excel)
    assert same(rs, baseline) and rs.problems == []
    tab = tmp_path / "tab.tsv"
    ratings.to_csv(tab, sep="\t", index=False)
    assert same(load_ratings(manifest, ratings_csv=tab), baseline)


def test_spaces_around_ids_do_not_split_a_rater(study, tmp_path):
    """'P01 ' typed in a spreadsheet made a second, partial rater of a third of P01's rows."""
    manifest, _, ratings, baseline = study
    spaced = ratings.copy()
    spaced.loc[::3, "participant"] = spaced.loc[::3, "participant"] + " "
    spaced.loc[1::3, "stimulus"] = " " + spaced.loc[1::3, "stimulus"]
    path = tmp_path / "spaced.csv"
    spaced.to_csv(path, index=False)
    assert same(load_ratings(manifest, ratings_csv=path), baseline)


def test_rows_without_a_participant_are_listed_and_the_run_goes_on(study, tmp_path):
    """pandas 3 keeps an empty cell of a text column as a missing value, which the old check
    for an empty id never saw: the run ended in a TypeError."""
    manifest, plain, _, baseline = study
    path = tmp_path / "gaps.csv"
    lines = plain.read_text().splitlines()
    lines[3:3] = [",SRC01,50", ""]  # a row without participant, then an empty line
    path.write_text("\n".join(lines) + "\n,,\n")
    rs = load_ratings(manifest, ratings_csv=path)
    assert same(rs, baseline)
    assert [(p.row, p.message) for p in rs.problems] == [(4, "no participant id; row left out")]
    lines[6] = lines[6].rsplit(",", 1)[0] + ",bad"
    path.write_text("\n".join(lines) + "\n")
    rows = [p.row for p in load_ratings(manifest, ratings_csv=path).problems]
    assert rows == [4, 7]  # line numbers of the file, the empty line counted


def test_a_decimal_comma_in_a_comma_separated_file_is_refused_by_line(study, tmp_path):
    manifest, plain, _, _ = study
    lines = plain.read_text().splitlines()
    who, what, _ = lines[5].split(",")
    quoted, unquoted = tmp_path / "quoted.csv", tmp_path / "unquoted.csv"
    quoted.write_text("\n".join([*lines[:5], f'{who},{what},"2,5"', *lines[6:]]) + "\n")
    with pytest.raises(AnalysisError, match=r"1 rating\(s\) are written with a decimal comma "
                                            r"\(line 6: '2,5'\); write decimals with a point"):
        load_ratings(manifest, ratings_csv=quoted)
    unquoted.write_text("\n".join([lines[0], *(ln.replace(".", ",") for ln in lines[1:])]))
    with pytest.raises(AnalysisError, match="more cells than its header; a decimal comma"):
        load_ratings(manifest, ratings_csv=unquoted)


def test_other_column_names_are_named_in_the_error(study, tmp_path):
    manifest, _, ratings, _ = study
    path = tmp_path / "named.csv"
    ratings.set_axis(["subject", "video", "score"], axis=1).to_csv(path, index=False)
    with pytest.raises(AnalysisError) as err:
        load_ratings(manifest, ratings_csv=path)
    assert "lacks column(s) participant, stimulus, rating (its columns: subject, video, " \
           "score); the analysis needs participant, stimulus and rating" in str(err.value)


def _without(manifest: Path, key: str, out: Path, **changes) -> Path:
    data = json.loads(manifest.read_text())
    data.pop(key, None)
    data.update(changes)
    out.write_text(json.dumps(data))
    return out


def test_acr_ratings_on_a_manifest_without_a_scale_are_refused(study, tmp_path, capsys):
    """1..5 read on the default 0..100 scale gave DMOS of 96 to 100, exit 0, no warning."""
    manifest, _, ratings, _ = study
    acr = ratings.assign(rating=np.clip(np.round(ratings["rating"] / 25) + 1, 1, 5).astype(int))
    path = tmp_path / "acr.csv"
    acr.to_csv(path, index=False)
    bare = _without(manifest, "scale", tmp_path / "bare.json")
    code = analyze(["dmos", "--manifest", str(bare), "--ratings", str(path), "--out",
                    str(tmp_path / "d.csv"), "--model", "mos"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert f"every rating is a whole number from {acr['rating'].min()} to " \
           f"{acr['rating'].max()}, but the manifest" in err[0] and "gives no scale" in err[0]
    given = _without(manifest, "scale", tmp_path / "acr.json",
                     scale={"min": 1, "max": 5, "labels": []})
    rs = load_ratings(given, ratings_csv=path)
    assert rs.scale_max == 5 and np.nanmax(rs.scores) <= 5
    wide = _without(manifest, "scale", tmp_path / "wide.json")  # 0..100 ratings: accepted
    assert load_ratings(wide, ratings_csv=study[1]).n_ratings == len(ratings)
    nolabels = _without(manifest, "scale", tmp_path / "nolabels.json",
                        scale={"min": 1, "max": 5})
    code = analyze(["dmos", "--manifest", str(nolabels), "--ratings", str(path), "--out",
                    str(tmp_path / "d.csv")])
    err = capsys.readouterr().err
    assert code == 2 and "scale.labels must be given for a range other than 0..100" in err


def test_ratings_given_once_against_the_default_three_repetitions_say_so(study, tmp_path,
                                                                         capsys):
    manifest, plain, _, _ = study
    data = json.loads(manifest.read_text())
    data["protocol"].pop("repetitions")
    default = tmp_path / "default.json"
    default.write_text(json.dumps(data))
    code = analyze(["dmos", "--manifest", str(default), "--ratings", str(plain), "--out",
                    str(tmp_path / "d.csv"), "--model", "mos"])
    err = capsys.readouterr().err
    assert code == 2
    assert "no rater rated a stimulus more than 1 time(s), but the manifest's " \
           "protocol.repetitions is 3" in err and "set protocol.repetitions to 1" in err
    assert "from a ratings CSV the plan is the manifest's stimuli x protocol.repetitions" in err


def test_a_stimulus_nobody_rated_leaves_everyone_complete(study, tmp_path, capsys):
    """A hidden reference nobody rated made every rater 'partial (96%)'; its conditions'
    MOS then stood in the dmos column and the dmos command said nothing."""
    manifest, _, ratings, _ = study
    path = tmp_path / "no_src02.csv"
    ratings[ratings["stimulus"] != "SRC02"].to_csv(path, index=False)
    rs = load_ratings(manifest, ratings_csv=path)
    assert np.allclose(rs.rater_info["completeness"], 1.0)
    out = tmp_path / "d.csv"
    code = analyze(["dmos", "--manifest", str(manifest), "--ratings", str(path), "--out",
                    str(out), "--model", "mos"])
    err = capsys.readouterr().err
    assert code == 0 and "no hidden-reference ratings for SRC02: their stimuli have no DMOS" \
        in err
    table = pd.read_csv(out)
    assert table.loc[table["reference"] == "SRC02", "dmos"].isna().all()
    assert table.loc[table["reference"] == "SRC01", "dmos"].notna().all()


def test_the_dmos_figure_says_why_a_scene_has_no_dmos(study, tmp_path, monkeypatch):
    """Saved to test-artifacts/analysis/ for a look: the scene without a rated hidden
    reference is an empty panel that says why, not a panel of MOS values among DMOS."""
    import analysis.figures as figures
    from analysis.pipeline import AnalysisConfig, run_analysis

    manifest, _, ratings, _ = study
    path = tmp_path / "no_src02.csv"
    ratings[ratings["stimulus"] != "SRC02"].to_csv(path, index=False)
    rs = load_ratings(manifest, ratings_csv=path)
    analysis = run_analysis(rs, AnalysisConfig(model="mos", n_boot=100, n_splits=50))
    built = []
    real = figures._save
    monkeypatch.setattr(figures, "_save", lambda fig, p, **kw: built.append(fig) or
                        real(fig, p, **kw))
    out = Path(__file__).resolve().parents[2] / "test-artifacts" / "analysis"
    out.mkdir(parents=True, exist_ok=True)
    assert figures.dmos_per_scene(analysis, out / "dmos_without_a_hidden_reference.png") \
        .is_file()
    panels = {ax.get_title(): [t.get_text() for t in ax.texts] for ax in built[0].axes}
    assert panels == {"scene1": ["blur"],  # the method under its levels
                      "scene2": ["blur", "no DMOS: its hidden reference\nwas not rated"]}


def test_rater_ids_with_numbers_sort_as_numbers():
    ids = ["P10", "P2", "p1", "P01", "a", "10", "9", 3]
    assert rater_order(ids) == ["3", "9", "10", "a", "P01", "p1", "P2", "P10"]


def test_numbered_raters_keep_their_ratings_in_numeric_order(study, tmp_path):
    """Raters 1..10 were ordered 1, 10, 2 in every table and on the rater axis."""
    manifest, _, ratings, baseline = study
    names = dict(zip(baseline.raters, ["2", "10", "1", "9"], strict=True))
    path = tmp_path / "numbered.csv"
    ratings.assign(participant=ratings["participant"].map(names)).to_csv(path, index=False)
    rs = load_ratings(manifest, ratings_csv=path)
    assert rs.raters == ["1", "2", "9", "10"]
    for old, new in names.items():
        assert np.array_equal(rs.scores[:, rs.raters.index(new)],
                              baseline.scores[:, baseline.raters.index(old)], equal_nan=True)
    facts = facts_from_rows(ratings.assign(participant=ratings["participant"].map(names)))
    assert list(facts.index) == ["1", "2", "9", "10"]
