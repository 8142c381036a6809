"""The command line and the report folder, end to end on a generated study; every input that
used to give a traceback or a silent wrong number now gives one line and exit code 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.cli import main
from analysis.exports import DMOS_COLUMNS
from stimuli_manifests import save_manifest
from stimuli_manifests.tables import DMOS, read_table


@pytest.fixture(scope="module")
def files(tmp_path_factory, study):
    root = tmp_path_factory.mktemp("study")
    manifest = save_manifest(study.manifest.manifest, root / "manifest.json")
    ratings = root / "ratings.csv"
    study.ratings.to_csv(ratings, index=False)
    rng = np.random.default_rng(0)
    cond = [s for s in study.quality.index if "_" in s]
    q = study.quality[cond].to_numpy()
    refs = [c.split("_")[0] for c in cond]
    scores = pd.concat([
        pd.DataFrame({"stimulus": cond, "reference": refs, "metric": "cgvqm-2",
                      "pooling": "mean", "score": q + rng.normal(0, 2, len(q)),
                      "direction": "higher-better", "backbone": "resnet18", "seconds": 0.1}),
        pd.DataFrame({"stimulus": cond, "reference": refs, "metric": "psnr", "pooling": "",
                      "score": -q + rng.normal(0, 9, len(q)), "direction": "lower-better",
                      "backbone": "random (untrained)", "seconds": 0.01}),
    ])
    metric = root / "scores.csv"
    scores.to_csv(metric, index=False)
    notes = root / "notes.md"
    notes.write_text("Simulated panel: rater P01 answers at random.")
    return {"manifest": manifest, "ratings": ratings, "metric": metric, "notes": notes,
            "root": root}


def test_report_end_to_end(files, tmp_path: Path, capsys) -> None:
    out = tmp_path / "report"
    rc = main(["report", "--manifest", str(files["manifest"]), "--ratings", str(files["ratings"]),
               "--metric", str(files["metric"]), "--notes", str(files["notes"]),
               "--bootstrap", "200", "--splits", "200", "--seed", "1", "--out", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "removed raters (p913): P01" in text and "cgvqm-2 (mean)" in text
    for name in ("report.html", "dmos.csv", "summary.json", "sureal_dataset.json",
                 "rating_matrix_p910.csv", "tables/icc.csv", "tables/metrics.csv",
                 "tables/significance_p.csv", "tables/williams_p.csv", "tables/comparisons.csv",
                 "tables/data_quality.csv", "tables/screening.csv", "tables/exclusions.csv",
                 "tables/problems.csv"):
        assert (out / name).is_file(), name
    figs = {p.stem for p in (out / "figures").glob("*.png")}
    assert figs >= {"dmos_per_scene", "metric_scatter", "metric_comparison", "metric_benchmark",
                    "metric_per_method", "inter_rater", "intra_rater", "rater_bias",
                    "rater_agreement", "ci_vs_raters", "split_half"}
    html = (out / "report.html").read_text()
    for fig in figs:
        assert f"figures/{fig}.png" in html
    glance = html[html.index("At a glance"): html.index("</div>", html.index("At a glance"))]
    assert "P01" in glance and "psnr" in glance and "random (untrained)" in glance
    assert html.index("At a glance") < html.index("Metrics versus humans")
    assert "Simulated panel" in html and "Methods and defaults" in html
    summary = json.loads((out / "summary.json").read_text())
    assert [r["rater"] for r in summary["removed_raters"]] == ["P01"]
    assert summary["outlier_method"] == "p913" and summary["min_completeness"] == 0.5
    assert summary["icc"]["ICC(2,k)"] > 0.9
    assert 0.8 < summary["ceiling"]["plcc"]["median"] <= 1
    assert summary["untrained_backbone"] == {"psnr": "random (untrained) backbone: random "
                                             "(untrained)"}
    metrics = {m["metric"]: m for m in summary["metrics"]}
    assert metrics["cgvqm-2 (mean)"]["plcc"] > metrics["psnr"]["plcc"] > 0
    assert metrics["psnr"]["srcc"] > 0  # lower-better, oriented
    assert summary["significance_p"]["cgvqm-2 (mean)"]["psnr"] < 0.05
    rows = read_table(out / "dmos.csv", DMOS)  # the versioned contract reads it back
    assert len(rows) == 70
    dmos = pd.read_csv(out / "dmos.csv")
    assert list(dmos.columns[: len(DMOS_COLUMNS)]) == list(DMOS_COLUMNS)
    assert dmos.columns[-1] == "format" and (dmos["format"] == DMOS.version).all()
    assert (dmos["n_ratings"] == 57).all()  # 19 raters kept x 3 repetitions


def test_subcommands(files, tmp_path: Path, capsys) -> None:
    common = ["--manifest", str(files["manifest"]), "--ratings", str(files["ratings"]),
              "--bootstrap", "50", "--splits", "50"]
    assert main(["dmos", *common, "--model", "mos", "--out", str(tmp_path / "d.csv")]) == 0
    d = pd.read_csv(tmp_path / "d.csv")
    assert {"quality", "scene", *DMOS_COLUMNS} <= set(d.columns)
    assert d["model"].iloc[0].startswith("MOS")
    assert main(["reliability", *common, "--outliers", "none"]) == 0
    assert "ICC(2,k)" in capsys.readouterr().out
    assert main(["compare", *common, "--metric", str(files["metric"]),
                 "--out", str(tmp_path / "cmp")]) == 0
    assert (tmp_path / "cmp" / "tables" / "metrics.csv").is_file()
    assert main(["export", *common, "--out", str(tmp_path / "exp")]) == 0
    matrix = pd.read_csv(tmp_path / "exp" / "rating_matrix_p910.csv", index_col=0)
    assert matrix.shape == (70, 60)  # all 20 raters x 3 repetitions as columns
    data = json.loads((tmp_path / "exp" / "sureal_dataset.json").read_text())
    assert len(data["dis_videos"]) == 70 and data["ref_score"] == 100.0


def test_sureal_input_needs_no_manifest(sureal_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "d.csv"
    assert main(["dmos", "--sureal", str(sureal_dir / "NFLX_dataset_public_raw.py"),
                 "--model", "mos", "--outliers", "none", "--out", str(out)]) == 0
    d = pd.read_csv(out)
    assert d["dmos"].iloc[10] == pytest.approx(2.1923076923076921)


def _constant(tmp_path: Path, files) -> list[str]:
    frame = pd.read_csv(files["ratings"]).assign(rating=50.0)
    path = tmp_path / "const.csv"
    frame.to_csv(path, index=False)
    return ["dmos", "--manifest", str(files["manifest"]), "--ratings", str(path), "--out",
            str(tmp_path / "d.csv")]


@pytest.mark.parametrize(("argv", "says"), [
    (["dmos", "--ratings", "x.csv", "--out", "d.csv"], "need --manifest"),
    (["dmos", "--sureal", "missing.py", "--out", "d.csv"], "does not exist"),
    (["report", "--sureal", "a.py", "--ratings", "b.csv", "--out", "o"], "exactly one"),
    ("alpha5", "alpha must lie between 0 and 0.5"),
    ("alphanan", "alpha must lie between 0 and 0.5"),
    ("seed", "seed must be a whole number >= 0"),
    ("outfile", "is an existing file"),
    ("outdir", "is a folder"),
    ("constant", "all 4200 ratings are equal"),
    ("completeness", "min-completeness must lie in [0, 1]"),
    # options the command would not read
    ("alpha-unused", "--alpha is the significance level of --outliers grubbs"),
    ("sureal-manifest", "a SUREAL dataset carries its own stimuli: drop --manifest"),
    ("vision-csv", "--exclude-failed-vision needs session files"),
])
def test_user_errors_exit_2_with_one_line(argv, says, files, capsys, tmp_path,
                                          monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    common = ["--manifest", str(files["manifest"]), "--ratings", str(files["ratings"])]
    (tmp_path / "afile").write_text("x")
    argv = {
        "alpha5": ["dmos", *common, "--alpha", "5", "--out", "d.csv"],
        "alphanan": ["dmos", *common, "--alpha", "nan", "--out", "d.csv"],
        "seed": ["dmos", *common, "--seed", "-1", "--out", "d.csv"],
        "outfile": ["report", *common, "--out", str(tmp_path / "afile")],
        "outdir": ["dmos", *common, "--out", str(tmp_path)],
        "constant": _constant(tmp_path, files) if argv == "constant" else None,
        "completeness": ["dmos", *common, "--min-completeness", "1.5", "--out", "d.csv"],
        "alpha-unused": ["dmos", *common, "--alpha", "0.01", "--out", "d.csv"],
        "sureal-manifest": ["dmos", "--sureal", "d.json", "--manifest", "m.json", "--out",
                            "d.csv"],
        "vision-csv": ["dmos", *common, "--exclude-failed-vision", "--out", "d.csv"],
    }.get(argv, argv) if isinstance(argv, str) else argv
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cgvq-analyze: error:"), err
    assert says in err[0] and "Traceback" not in err[0]


def test_alpha_is_accepted_where_a_test_uses_it(files, tmp_path: Path) -> None:
    """Grubbs screening and the metric comparisons read --alpha; p913 alone does not."""
    common = ["--manifest", str(files["manifest"]), "--ratings", str(files["ratings"]),
              "--alpha", "0.01", "--bootstrap", "20", "--splits", "20"]
    assert main(["dmos", *common, "--outliers", "grubbs", "--out",
                 str(tmp_path / "d.csv")]) == 0
    assert main(["compare", *common, "--metric", str(files["metric"])]) == 0


@pytest.mark.parametrize(("command", "option", "value"), [
    ("dmos", "--bootstrap", "1000000000000"),
    ("reliability", "--splits", "100000000000"),
    ("report", "--bootstrap", "0"),
    ("compare", "--splits", "100001"),
])
def test_resample_options_have_a_range(command, option, value, files, tmp_path: Path,
                                       capsys) -> None:
    """--bootstrap 10**12 and --splits 10**11 used to end in a MemoryError traceback."""
    out = tmp_path / "out"
    argv = [command, "--manifest", str(files["manifest"]), "--ratings", str(files["ratings"]),
            option, value]
    argv += {"dmos": ["--out", str(out / "d.csv")], "report": ["--out", str(out)],
             "compare": ["--metric", str(files["metric"])]}.get(command, [])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"cgvq-analyze: error: {option} must be a whole number from 1 to 100000, "
                   f"got {value}"]
    assert not out.exists()


def test_notes_that_are_not_utf8_are_refused_before_any_work(files, tmp_path: Path,
                                                             capsys) -> None:
    notes = tmp_path / "clip.mp4"
    notes.write_bytes(b"\xc3\x28\x00\x00\x00\x18ftypmp42" + bytes(range(256)))
    out = tmp_path / "report"
    assert main(["report", "--manifest", str(files["manifest"]), "--ratings",
                 str(files["ratings"]), "--notes", str(notes), "--bootstrap", "10",
                 "--splits", "10", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cgvq-analyze: error: --notes file "), err
    assert str(notes) in err[0] and "is not UTF-8 text" in err[0]
    assert captured.out == "" and not out.exists()


@pytest.mark.parametrize(("name", "text", "says"), [
    ("huge.py", "ref_videos = [{'content_id': 0, 'path': 'a'}]\n"
                "dis_videos = [{'content_id': 0, 'path': 'b', 'os': [1.0] * 10000000000}]\n",
     "more than 20,000,000 values"),
    ("power.py", "x = [0] * 10**12\n", "not plain data"),
    ("deep.py", "x = " + "[" * 150 + "]" * 150 + "\n", "nested deeper than 64"),
    ("deeper.py", "x = " + "[" * 5000 + "]" * 5000 + "\n", "nested"),
    ("negative.py", "x = -'abc'\n", "applies to numbers only"),
    ("unhashable.py", "x = {[1]: 2}\n", "is not a plain value"),
    ("refscore.py", "ref_score = 'five'\nref_videos = [{'content_id': 0, 'path': 'a'}]\n"
                    "dis_videos = [{'content_id': 0, 'path': 'b', 'os': [1, 2]}]\n",
     "ref_score 'five' is not a finite number"),
    ("deep.json", "[" * 100000 + "]" * 100000, "nested too deeply"),
    ("novotes.json", json.dumps({"ref_videos": [{"content_id": 0, "path": "a"}],
                                 "dis_videos": [{"content_id": 0, "path": "b",
                                                 "os": [["x"], {"os": 1}]}]}),
     "no numeric votes"),
])
def test_hostile_sureal_files_exit_2(name, text, says, tmp_path: Path, capsys) -> None:
    path = tmp_path / name
    path.write_text(text)
    assert main(["dmos", "--sureal", str(path), "--out", str(tmp_path / "d.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err


def test_text_votes_are_reported_not_fatal(tmp_path: Path, capsys) -> None:
    path = tmp_path / "text.json"
    dis = [{"content_id": c, "path": f"d{c}{k}", "os": [k + 1.0, "bad", k + 1.5, 2.0 + c]}
           for c in range(3) for k in range(3)]
    dis += [{"content_id": c, "path": f"r{c}", "os": [5.0, 4.5, 5.0, 4.0]} for c in range(3)]
    path.write_text(json.dumps({"ref_score": 5, "ref_videos": [
        {"content_id": c, "path": f"r{c}"} for c in range(3)], "dis_videos": dis}))
    assert main(["dmos", "--sureal", str(path), "--model", "mos", "--outliers", "none",
                 "--out", str(tmp_path / "d.csv")]) == 0
    err = capsys.readouterr().err
    assert "vote 'bad' is not a number" in err


def test_mle_fallback_is_said_on_the_console(tmp_path: Path, capsys, monkeypatch) -> None:
    """When SUREAL's MLE diverges the console says so (not only report.html)."""
    import analysis.scores as scores

    monkeypatch.setattr(scores, "plausible", lambda out, rs, calls=[0]:
                        calls.append(1) or len(calls) > 2)
    from analysis.synthetic import synthetic_study

    st = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=6, repetitions=2,
                         seed=2)
    m = save_manifest(st.manifest.manifest, tmp_path / "m.json")
    st.ratings.to_csv(tmp_path / "r.csv", index=False)
    assert main(["dmos", "--manifest", str(m), "--ratings", str(tmp_path / "r.csv"),
                 "--outliers", "none", "--out", str(tmp_path / "d.csv")]) == 0
    err = capsys.readouterr().err
    assert "warning: SUREAL MLE did not converge" in err and "fell back" in err
