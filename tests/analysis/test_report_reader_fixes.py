"""The report as a researcher writing a paper reads it (findings of the reader's audit): p-values
that cannot be 0, no per-method interval where the data cannot give one, a rerun that leaves
nothing of the last one, vector figures, axes that show whole whiskers and plain log ticks,
panel-size text without NaN or '3th', a small panel said to be one, where every number came
from, and a metric that lacks stimuli named."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis import AnalysisConfig, ratings_from_frame, run_analysis
from analysis import figures as figures_module
from analysis.cli import main
from analysis.metrics import MetricScores, validate_metrics
from analysis.report_html import curve_text, ordinal
from analysis.synthetic import synthetic_study
from stimuli_manifests import save_manifest


def _frame(n: int, methods: np.ndarray, seed: int = 2) -> tuple[pd.DataFrame, np.ndarray]:
    rng = np.random.default_rng(seed)
    d0 = rng.uniform(20, 100, n)
    frame = pd.DataFrame({"stimulus": [f"S{i}" for i in range(n)], "reference": "R",
                          "scene": "x", "method": methods, "level": 1, "dmos": d0,
                          "ci95_low": d0 - 3, "ci95_high": d0 + 3, "is_hidden_reference": False})
    return frame, d0


def _scores(frame: pd.DataFrame, values: dict[str, np.ndarray]) -> MetricScores:
    return MetricScores(pd.concat([pd.DataFrame({
        "stimulus": frame["stimulus"], "reference": "R", "metric": name, "score": v,
        "direction": "higher-better"}) for name, v in values.items()], ignore_index=True))


def test_a_paired_bootstrap_p_is_never_zero():
    frame, d0 = _frame(30, np.array(["a", "b", "c"])[np.arange(30) % 3])
    rng = np.random.default_rng(1)
    good, bad = d0 + rng.normal(0, 1, 30), d0 + rng.normal(0, 40, 30)
    v = validate_metrics(frame, _scores(frame, {"good": good, "bad": bad}), n_boot=200)
    c = v.comparisons.set_index(["scope", "metric_a", "metric_b"])
    # every resample favours 'good': (0 + 1) / (200 + 1), not 0
    assert c.loc[("all", "good", "bad"), "boot_p"] == pytest.approx(1 / 201)
    assert (c["boot_n"] == 200).all()  # the B of (k + 1) / (B + 1), in the table
    assert c.loc[("all", "bad", "good"), "boot_p"] == pytest.approx(1.0)


def test_per_method_intervals_only_where_the_data_can_give_one():
    n = 26  # method 'a' of 8 stimuli in perfect order, 'b' of 4, 'c' of 14 noisy ones
    methods = np.array(["a"] * 8 + ["b"] * 4 + ["c"] * 14)
    frame, d0 = _frame(n, methods)
    q = d0 + np.where(methods == "a", 0.0, np.random.default_rng(3).normal(0, 15, n))
    v = validate_metrics(frame, _scores(frame, {"m": q}), n_boot=300)
    rows = v.per_method.set_index("method")
    assert rows.loc["a", "srcc"] == pytest.approx(1.0)
    # most resamples of 'a' are in perfect order too: no spread on Fisher's z, no interval
    assert np.isnan(rows.loc["a", ["srcc_ci95_low", "srcc_ci95_high"]].to_numpy(float)).all()
    # four stimuli: Student's t with 1 degree of freedom would stretch any interval past use
    assert np.isnan(rows.loc["b", ["rmse_ci95_low", "rmse_ci95_high", "plcc_ci95_low"]]
                    .to_numpy(float)).all()
    lo, hi = rows.loc["c", ["srcc_ci95_low", "srcc_ci95_high"]].to_numpy(float)
    assert -1 < lo < rows.loc["c", "srcc"] < hi < 1  # a real interval where one exists


def test_ordinals():
    assert [ordinal(n) for n in (1, 2, 3, 4, 11, 12, 13, 21, 22, 23, 101, 111)] == [
        "1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "23rd", "101st",
        "111th"]


@pytest.fixture(scope="module")
def small_study():
    return synthetic_study(n_scenes=2, methods=("blur", "noise"), levels=3, n_raters=3,
                           repetitions=1, seed=4)


def test_a_three_rater_panel_is_described_as_it_is(small_study, tmp_path):
    st = small_study
    rs = ratings_from_frame(st.ratings, st.manifest)
    config = AnalysisConfig(model="mos", outliers="none", n_boot=50, n_splits=20, ci_draws=5)
    a = run_analysis(rs, config, progress=False)
    # the CI curve starts at 3 raters (two raters' t quantile is 12.7), so 3 make no curve
    assert a.ci_curve is None
    from analysis.report import write_report

    html = write_report(a, tmp_path / "r").read_text()
    assert "No curve of the CI width against the number of raters" in html
    assert not (tmp_path / "r" / "figures" / "ci_vs_raters.png").exists()
    assert "Only 3 rater(s): too few for the human ceiling" in html
    assert "{ceiling}" not in html and "grey band" not in html
    assert "No split-half ceiling: it needs at least 4 raters, and 3 remain" in html


def test_a_four_rater_curve_starts_at_three():
    """The shortest curve: 3 and 4 raters, so one reduction (by the 4th), said in words."""
    st = synthetic_study(n_scenes=2, methods=("blur", "noise"), levels=3, n_raters=4,
                         repetitions=1, seed=4)
    config = AnalysisConfig(model="mos", outliers="none", n_boot=50, n_splits=20, ci_draws=5)
    a = run_analysis(ratings_from_frame(st.ratings, st.manifest), config, progress=False)
    assert list(a.ci_curve.n_raters) == [3, 4]
    assert list(a.ci_curve.reduction_per_rater()) == [4]
    text = curve_text(a)
    assert "nan" not in text and "4th participant" in text and "3rd" not in text


@pytest.fixture(scope="module")
def study_files(tmp_path_factory):
    st = synthetic_study(n_scenes=3, methods=("blur", "noise"), levels=3, n_raters=8,
                         repetitions=1, seed=6)
    root = tmp_path_factory.mktemp("reader")
    manifest = save_manifest(st.manifest.manifest, root / "manifest.json")
    ratings = root / "ratings.csv"
    st.ratings.to_csv(ratings, index=False)
    cond = [s for s in st.quality.index if "_" in s]
    q = st.quality[cond].to_numpy()
    rng = np.random.default_rng(0)
    rows = []
    for name, noise in (("good", 3.0), ("weak", 25.0)):
        rows.append(pd.DataFrame({"stimulus": cond, "reference": [c.split("_")[0] for c in cond],
                                  "metric": name, "score": q + rng.normal(0, noise, len(q)),
                                  "direction": "higher-better"}))
    scores = root / "scores.csv"
    pd.concat(rows).to_csv(scores, index=False)
    partial = root / "partial.csv"
    pd.concat(rows).iloc[3:].to_csv(partial, index=False)  # 'good' lacks its first 3 stimuli
    return {"manifest": manifest, "ratings": ratings, "scores": scores, "partial": partial,
            "missing": cond[:3]}


def _report(files: dict, out: Path, *extra: str) -> int:
    return main(["report", "--manifest", str(files["manifest"]), "--ratings",
                 str(files["ratings"]), "--bootstrap", "60", "--splits", "20", "--outliers",
                 "none", "--out", str(out), *extra])


# about 15 s: CI runs it after `make test` (.ci/run), as `make test-slow` does
@pytest.mark.slow
def test_a_rerun_leaves_nothing_of_the_last_and_figures_come_as_pdf(study_files, tmp_path):
    out = tmp_path / "report"
    assert _report(study_files, out, "--metric", str(study_files["scores"])) == 0
    pngs = sorted((out / "figures").glob("*.png"))
    assert pngs and all(p.with_suffix(".pdf").read_bytes().startswith(b"%PDF") for p in pngs)
    assert (out / "tables" / "metrics.csv").is_file()
    summary = json.loads((out / "summary.json").read_text())
    inputs = summary["inputs"]
    sha = hashlib.sha256(study_files["manifest"].read_bytes()).hexdigest()
    assert inputs["manifest"]["sha256"] == sha
    assert inputs["metric"][0]["sha256"] == hashlib.sha256(
        study_files["scores"].read_bytes()).hexdigest()
    assert inputs["command"].startswith("cgvq-analyze report --manifest")
    html = (out / "report.html").read_text()
    assert sha[:12] in html
    # 8 raters: a ceiling is drawn, and the captions say where
    assert "the grey band is the agreement of two half panels" in html and "{ceiling}" not in html
    # with a metric, the DMOS caption names its markers
    assert ("(metric predictions after the logistic mapping as hollow black markers, side by "
            "side to the right of each DMOS") in html
    # the same folder without --metric: no metric table or figure of the first run is left
    assert _report(study_files, out) == 0
    _says_only_what_is_shown((out / "report.html").read_text(), out)
    left = [p.name for p in (out / "tables").iterdir()] + [
        p.name for p in (out / "figures").iterdir()]
    assert not [n for n in left if n.startswith(("metric", "significance", "williams",
                                                 "comparisons"))], left


@pytest.mark.slow  # about 11 s here: CI runs it after `make test` (.ci/run)
def test_a_metric_lacking_stimuli_is_named(study_files, tmp_path, capsys):
    out = tmp_path / "report"
    assert _report(study_files, out, "--metric", str(study_files["partial"])) == 0
    problems = pd.read_csv(out / "tables" / "problems.csv")
    said = problems[(problems["source"] == "good")  # the metric, named once (not "good: good:")
                    & problems["message"].str.startswith("3 of")]
    assert len(said) == 1
    assert all(s in said["message"].iloc[0] for s in study_files["missing"])


@pytest.mark.slow  # about 9 s here: CI runs it after `make test` (.ci/run)
def test_axes_show_whole_whiskers_and_log_ticks_are_plain(study_files, tmp_path, monkeypatch):
    drawn: dict[str, object] = {}
    save = figures_module._save

    def keep(fig, path, **kw):
        drawn[Path(path).stem] = fig
        return save(fig, path, **kw)

    monkeypatch.setattr(figures_module, "_save", keep)
    assert _report(study_files, tmp_path / "r", "--metric", str(study_files["scores"])) == 0
    table = pd.read_csv(tmp_path / "r" / "tables" / "metrics.csv")
    lowest = float(np.nanmin(table[["plcc_ci95_low", "srcc_ci95_low"]].to_numpy(float)))
    assert drawn["metric_benchmark"].axes[0].get_xlim()[0] <= lowest
    assert drawn["metric_comparison"].axes[0].get_ylim()[0] <= lowest
    scenes = drawn["dmos_per_scene"].axes  # one DMOS axis for every scene
    assert len({ax.get_ylim() for ax in scenes}) == 1
    labels = [t.get_text() for ax in scenes for t in ax.get_xticklabels()]
    assert "L1" in labels and "L3" in labels  # levels, each method named under its levels
    names = [t.get_text() for ax in scenes for t in ax.texts]
    assert "blur" in names and "noise" in names  # whole method names
    log_axes = [ax for ax in drawn["ci_vs_raters"].axes if ax.get_yscale() == "log"]
    assert log_axes
    for ax in log_axes:  # the labels as saved (savefig drew them)
        labels = [t.get_text() for t in ax.get_yticklabels()]
        assert labels and not any("$" in t or "mathdefault" in t for t in labels), labels


def test_a_numeric_column_has_one_number_of_decimals():
    from analysis.report_html import format_column

    def col(*v):
        return format_column(pd.Series(v, dtype=float))

    assert col(0.9, 0.9525, -0.07281, np.nan) == ["0.9000", "0.9525", "-0.0728", ""]
    assert col(27.98446, 7.41, 7.776) == ["27.98", "7.41", "7.78"]
    assert col(28.0, 12.0) == ["28", "12"]  # counts stay whole
    assert col(1234.5678, 2.25) == ["1235", "2"]
    assert col(0.0, 0.0) == ["0", "0"] and col(np.nan) == [""]
    assert format_column(pd.Series(["a", None, True])) == ["a", "", "yes"]


def test_the_screening_section_describes_its_own_rule(study_files, tmp_path, monkeypatch):
    """The sentence over the per-rater table named P.913's columns for every rule."""
    from analysis import load_ratings
    from analysis import report as report_module

    monkeypatch.setattr(report_module, "draw_all", lambda a, folder: {})  # text only
    rs = load_ratings(study_files["manifest"], ratings_csv=study_files["ratings"])
    for rule, says in (("bt500", "outside_share: share"), ("grubbs", "deviation: mean"),
                       ("p913", "r1: with the leave-one-out")):
        a = run_analysis(rs, AnalysisConfig(model="mos", outliers=rule, n_boot=20,
                                            n_splits=10, ci_draws=2), progress=False)
        from analysis.report import write_report

        html = write_report(a, tmp_path / rule).read_text()
        section = html[html.index("id='screening'"):html.index("id='screening'") + 1500]
        assert says in section and ("r1: with" in section) == (rule == "p913")


def _says_only_what_is_shown(html: str, out: Path) -> None:
    """A report of a ratings CSV has no viewing times, toggles or frames: those columns are
    left out, and so is their legend; the DMOS caption names metric markers only when a
    metric was given, and the agreement caption repetitions only when there are some."""
    assert "black markers" not in html and "{metrics}" not in html
    assert "uses only the raters kept), with the flag thresholds" in html
    quality = html.split("id='quality'", 1)[1].split("<h2", 1)[0]
    assert "r others = Pearson r" in quality and "hidden ref = mean" in quality
    for column in ("view s", "toggles", "frames", "timing"):
        assert f"<th>{column}</th>" not in quality and f"{column} = " not in quality, column
    csv = pd.read_csv(out / "tables" / "data_quality.csv")
    assert csv["median_viewing_s"].isna().all()  # nothing to show: the CSV has no such data
