"""The command line and the report folder, end to end on a generated study."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.cli import main
from analysis.exports import DMOS_COLUMNS
from stimuli_manifests import save_manifest


@pytest.fixture(scope="module")
def files(tmp_path_factory, study):
    root = tmp_path_factory.mktemp("study")
    manifest = save_manifest(study.manifest.manifest, root / "manifest.json")
    ratings = root / "ratings.csv"
    study.ratings.to_csv(ratings, index=False)
    rng = np.random.default_rng(0)
    cond = [s for s in study.quality.index if "_" in s]
    q = study.quality[cond].to_numpy()
    scores = pd.concat([
        pd.DataFrame({"stimulus": cond, "reference": [c.split("_")[0] for c in cond],
                      "metric": "cgvqm-2", "pooling": "mean", "score": q + rng.normal(0, 2, len(q)),
                      "backbone": "resnet18", "seconds": 0.1}),
        pd.DataFrame({"stimulus": cond, "reference": [c.split("_")[0] for c in cond],
                      "metric": "psnr", "pooling": "", "score": -q + rng.normal(0, 9, len(q)),
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
    assert "removed raters (grubbs): P01" in text and "cgvqm-2 (mean)" in text
    for name in ("report.html", "dmos.csv", "summary.json", "sureal_dataset.json",
                 "rating_matrix_p910.csv", "tables/icc.csv", "tables/metrics.csv",
                 "tables/significance_p.csv", "tables/problems.csv"):
        assert (out / name).is_file(), name
    figs = {p.stem for p in (out / "figures").glob("*.png")}
    assert figs >= {"dmos_per_scene", "metric_scatter", "metric_comparison", "inter_rater",
                    "intra_rater", "rater_bias", "ci_vs_raters", "split_half"}
    html = (out / "report.html").read_text()
    for fig in figs:
        assert f"figures/{fig}.png" in html
    assert "UNTRAINED" in html and html.index("UNTRAINED") < html.index("Metrics versus humans")
    assert "Simulated panel" in html
    summary = json.loads((out / "summary.json").read_text())
    assert [r["rater"] for r in summary["removed_raters"]] == ["P01"]
    assert summary["icc"]["ICC(2,k)"] > 0.9
    assert 0.8 < summary["ceiling"]["plcc"]["median"] <= 1
    assert summary["untrained_backbone"] == {"psnr": "random (untrained)"}
    metrics = {m["metric"]: m for m in summary["metrics"]}
    assert metrics["cgvqm-2 (mean)"]["plcc"] > metrics["psnr"]["plcc"]
    assert summary["significance_p"]["cgvqm-2 (mean)"]["psnr"] < 0.05
    dmos = pd.read_csv(out / "dmos.csv")
    assert list(dmos.columns[: len(DMOS_COLUMNS)]) == list(DMOS_COLUMNS)
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
    assert matrix.shape == (70, 60)  # 20 raters x 3 repetitions as columns
    data = json.loads((tmp_path / "exp" / "sureal_dataset.json").read_text())
    assert len(data["dis_videos"]) == 70 and data["ref_score"] == 100.0


def test_sureal_input_needs_no_manifest(sureal_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "d.csv"
    assert main(["dmos", "--sureal", str(sureal_dir / "NFLX_dataset_public_raw.py"),
                 "--model", "mos", "--outliers", "none", "--out", str(out)]) == 0
    d = pd.read_csv(out)
    assert d["dmos"].iloc[10] == pytest.approx(2.1923076923076921)


@pytest.mark.parametrize("argv", [
    ["dmos", "--ratings", "x.csv", "--out", "d.csv"],                 # no manifest
    ["dmos", "--sureal", "missing.py", "--out", "d.csv"],             # missing file
    ["report", "--sureal", "a.py", "--ratings", "b.csv", "--out", "o"],  # two sources
])
def test_user_errors_exit_2_with_one_line(argv, capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cgvq-analyze: error:")
    assert "Traceback" not in err[0]


def test_report_from_session_files(tmp_path: Path, capsys) -> None:
    session = pytest.importorskip("study_app.session")
    if not hasattr(session, "SessionStore"):
        pytest.skip("study_app.session has no SessionStore")
    from analysis.synthetic import synthetic_study

    st = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=5, repetitions=2,
                         noise_sd=4, seed=8)
    manifest = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    for rater, rows in st.ratings.groupby("participant"):
        plan = [session.PlannedTrial(index=i, stimulus=r.stimulus, reference=r.reference,
                                     repetition=int(r.repetition),
                                     is_hidden_reference=bool(r.is_hidden_reference))
                for i, r in enumerate(rows.itertuples())]
        store = session.SessionStore.create(tmp_path / "s" / f"{rater}.sqlite",
                                            participant=rater, study_id="synthetic",
                                            manifest_sha256=None, seed=0, app_version="t",
                                            plan=plan)
        for i, r in enumerate(rows.itertuples()):
            store.record(i, session.TrialResult(rating=float(r.rating), rt_ms=900.0,
                                                n_toggles=0, ms_on_reference=0.0,
                                                ms_on_test=900.0,
                                                presented_at="2026-01-01T00:00:00Z"))
        store.close()
    out = tmp_path / "rep"
    assert main(["report", "--manifest", str(manifest), "--sessions", str(tmp_path / "s"),
                 "--model", "mos", "--outliers", "none", "--bootstrap", "20", "--splits", "20",
                 "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_ratings_used"] == len(st.ratings) and summary["n_raters_used"] == 5
    dmos = pd.read_csv(out / "dmos.csv").set_index("stimulus")
    mos = st.ratings.groupby("stimulus")["rating"].mean()
    assert dmos.loc["SRC01_HRC01", "dmos"] == pytest.approx(mos["SRC01_HRC01"] - mos["SRC01"]
                                                            + 100)
