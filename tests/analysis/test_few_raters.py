"""A report of two raters (a pilot's, say): its DMOS get no interval, and it says why."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

import analysis.figures as figures_module
from analysis.inputs import ratings_from_frame
from analysis.pipeline import AnalysisConfig, run_analysis
from analysis.report import write_report
from analysis.synthetic import synthetic_study


def test_two_raters_give_dmos_without_intervals_and_say_why(tmp_path, monkeypatch) -> None:
    st = synthetic_study(n_scenes=2, methods=("blur", "noise"), levels=3, n_raters=2, seed=3)
    rs = ratings_from_frame(st.ratings, st.manifest)
    drawn = {}
    save = figures_module._save

    def keep(fig, path, **kw):
        drawn[Path(path).stem] = fig
        return save(fig, path, **kw)

    monkeypatch.setattr(figures_module, "_save", keep)
    a = run_analysis(rs, AnalysisConfig(outliers="none", n_boot=50, n_splits=10, ci_draws=4),
                     progress=False)
    out = tmp_path / "report"
    write_report(a, out)
    d = pd.read_csv(out / "dmos.csv")
    cond = d[~d["is_hidden_reference"]]
    assert len(cond) == 12 and cond["dmos"].notna().all()
    assert cond["ci95_low"].isna().all() and cond["ci95_high"].isna().all()
    text = " ".join((out / "methods.txt").read_text(encoding="utf-8").split())
    assert ("No DMOS has an interval: every stimulus was rated, with its reference, by fewer "
            "than 3 raters") in text
    legend = [t.get_text() for t in drawn["dmos_per_scene"].legends[0].get_texts()]
    assert "no bar: fewer than 3 raters" in legend
