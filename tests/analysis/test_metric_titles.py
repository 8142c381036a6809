"""A metric's title (the scores' optional ``title`` column): prose and figures print it, the
tables keep the id; one title per metric and no title shared by two metrics."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from analysis.cli import main
from analysis.errors import AnalysisError
from analysis.metric_scores import load_metric_scores
from analysis.synthetic import synthetic_study
from stimuli_manifests import save_manifest


def _write(tmp_path, rows: list[dict], name: str = "s.csv"):
    path = tmp_path / name
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def _row(metric: str, stimulus: str, score: float, **extra) -> dict:
    return {"stimulus": stimulus, "reference": "R", "metric": metric, "score": score,
            "direction": "higher-better", **extra}


def test_titles_are_read_with_their_pooling_and_default_to_the_id(tmp_path):
    new = _write(tmp_path, [_row("cgvqm-2", "A", 1.0, title="CGVQM-2", pooling="mean"),
                            _row("psnr", "A", 30.0, title="PSNR", pooling=""),
                            _row("mine", "A", 0.3, title="", pooling="")], "new.csv")
    # a file without the column (cgvq-scores/1.0, or written by hand) beside it
    old = _write(tmp_path, [_row("psnr", "B", 31.0), _row("other", "B", 2.0)], "old.csv")
    scores = load_metric_scores([new, old])
    assert scores.titles == {"cgvqm-2 (mean)": "CGVQM-2 (mean)", "psnr": "PSNR",
                             "mine": "mine", "other": "other"}
    assert scores.title("psnr") == "PSNR" and scores.title("unknown") == "unknown"


def test_two_titles_for_one_metric_or_one_title_for_two_are_refused(tmp_path):
    two = _write(tmp_path, [_row("psnr", "A", 30.0, title="PSNR"),
                            _row("psnr", "B", 31.0, title="Psnr")])
    with pytest.raises(AnalysisError, match=r"metric 'psnr' has several titles \('PSNR', "
                                            r"'Psnr'\)"):
        load_metric_scores([two])
    shared = _write(tmp_path, [_row("ssim", "A", 0.9, title="SSIM"),
                               _row("ssim-y", "A", 0.8, title="SSIM")], "shared.csv")
    with pytest.raises(AnalysisError, match="metrics 'ssim' and 'ssim-y' share the title 'SSIM'"):
        load_metric_scores([shared])
    # a title that is another metric's id is just as ambiguous in prose
    clash = _write(tmp_path, [_row("a", "A", 1.0, title="b"), _row("b", "A", 2.0)], "clash.csv")
    with pytest.raises(AnalysisError, match="share the title 'b'"):
        load_metric_scores([clash])


def test_the_command_line_names_the_clash_in_one_line(tmp_path, capsys):
    st = synthetic_study(n_scenes=2, methods=("blur",), levels=2, n_raters=4, seed=1)
    save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    st.ratings.to_csv(tmp_path / "ratings.csv", index=False)
    two = _write(tmp_path, [_row("psnr", "A", 30.0, title="PSNR"),
                            _row("psnr", "B", 31.0, title="Psnr")])
    rc = main(["report", "--manifest", str(tmp_path / "manifest.json"), "--ratings",
               str(tmp_path / "ratings.csv"), "--metric", str(two), "--out",
               str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "several titles" in err


def test_prose_and_the_report_print_the_titles(tmp_path, monkeypatch):
    import analysis.figures as figures

    drawn = {}
    save = figures._save

    def keep(fig, path, **kw):
        drawn[path.stem] = fig
        return save(fig, path, **kw)

    monkeypatch.setattr(figures, "_save", keep)
    st = synthetic_study(n_scenes=3, methods=("blur", "noise"), levels=3, n_raters=8, seed=6)
    save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    st.ratings.to_csv(tmp_path / "ratings.csv", index=False)
    cond = [s for s in st.quality.index if "_" in s]
    rng = np.random.default_rng(0)
    pd.concat([pd.DataFrame({
        "stimulus": cond, "reference": [c.split("_")[0] for c in cond], "metric": name,
        "title": title, "score": st.quality[cond].to_numpy() + rng.normal(0, sd, len(cond)),
        "direction": "higher-better", "backbone": backbone,
        "versions": '{"implementation":"labmetric 2.1"}'})
        for name, title, sd, backbone in (("good", "GoodQ", 3.0, ""),
                                          ("weak", "WeakQ", 25.0, "random(seed=0)"))]
    ).to_csv(tmp_path / "scores.csv", index=False)
    out = tmp_path / "out"
    assert main(["report", "--manifest", str(tmp_path / "manifest.json"), "--ratings",
                 str(tmp_path / "ratings.csv"), "--bootstrap", "40", "--splits", "20",
                 "--outliers", "none", "--metric", str(tmp_path / "scores.csv"),
                 "--out", str(out)]) == 0
    text = " ".join((out / "methods.txt").read_text().split())
    table = pd.read_csv(out / "tables" / "metrics.csv").set_index("metric")
    assert list(table.index[:2]) == ["good", "weak"]  # the tables keep the ids
    for name, title in (("good", "GoodQ"), ("weak", "WeakQ")):
        assert f"{title}: PLCC {table.loc[name, 'plcc']:.3f}" in text
    assert not re.search(r"\b(good|weak): PLCC", text)
    assert "Implementations: GoodQ and WeakQ: labmetric 2.1." in text
    assert "[Not the published metric: WeakQ ran with random (untrained) backbone" in text
    if "over" in text:
        assert "GoodQ over WeakQ" in text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["metric_titles"] == {"good": "GoodQ", "weak": "WeakQ"}
    # the methods it names, cited at the end: Williams' t and Steiger's Z with two metrics
    paragraphs = (out / "methods.txt").read_text().split("\n\n")
    refs = paragraphs[paragraphs.index("References (the sources of the methods named above):")
                      + 1:]
    for first_words in ("Li, Z., Bampis", "ITU-T Recommendation P.910", "ITU-T Recommendation "
                        "P.1401", "Sheikh, H. R.", "Jindal, A.", "Williams, E. J.",
                        "Steiger, J. H.", "Shrout, P. E."):
        assert any(r.startswith(first_words) for r in refs), first_words
    assert not any(r.startswith("Grubbs") for r in refs)  # no screening was applied
    html = (out / "report.html").read_text()
    assert "<th>title</th>" in html and "<td>GoodQ</td>" in html
    # the figures name the metrics by title; the flagged one is marked in each
    ticks = [t.get_text() for t in drawn["metric_comparison"].axes[0].get_xticklabels()]
    assert ticks[:2] == ["GoodQ", "WeakQ\n[FLAGGED]"]
    hatched = {b.get_hatch() for b in drawn["metric_comparison"].axes[0].patches}
    assert hatched == {None, "//"}
    scatter = [ax.get_title().split("\n")[0] for ax in drawn["metric_scatter"].axes]
    assert scatter == ["GoodQ", "WeakQ [FLAGGED]"]
    benchmark = [t.get_text() for t in drawn["metric_benchmark"].axes[0].get_yticklabels()]
    assert sorted(benchmark) == ["GoodQ", "WeakQ  [FLAGGED]"]
    # the DMOS figure: each metric's predictions beside the DMOS, side by side in the
    # legend's order, never on the DMOS's own spot or in the next stimulus's slot
    ax = drawn["dmos_per_scene"].axes[0]
    lines = {ln.get_label(): ln for ln in ax.get_lines() if ln.get_label() in ("GoodQ", "WeakQ")}
    offsets = {name: np.unique(np.round(ln.get_xdata() % 1, 9)) for name, ln in lines.items()}
    assert len(offsets["GoodQ"]) == len(offsets["WeakQ"]) == 1
    assert 0 < offsets["GoodQ"][0] < offsets["WeakQ"][0] < 0.5
