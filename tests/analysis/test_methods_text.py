"""The report's "For the paper" text: every number it states is checked against a second
computation (pingouin on the kept raters, the known truth of the generated study, the
published layout of the Netflix dataset), and it says only what was computed."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pingouin as pg
import pytest

from analysis.cli import main
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
    n_stim = len(st.quality)
    assert text.startswith(f"10 participants gave valid ratings of {n_stim} stimuli on a "
                           "0 to 100 scale (full design: every stimulus rated 2 times")
    removed = sorted(pd.read_csv(out / "tables" / "outliers.csv", dtype={"rater": str})["rater"])
    assert removed == sorted(st.outliers)  # the two random raters, and only they
    kept = sorted(set(st.ratings["participant"]) - set(removed))
    assert f"2 raters were removed. The analysis uses {len(kept)} raters and " \
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
    assert "human ceiling (split-half): PLCC" not in text
    assert re.search(r"good over weak \(p = [0-9.e-]+\)", text)
    assert "weak over good" not in text


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
    assert text.startswith("30 participants gave valid ratings of 79 stimuli on a 1 to 5 "
                           "scale (full design: every stimulus rated once by every rater).")
    assert "4 raters were removed. The analysis uses 26 raters and 2054 ratings." in text
    assert "DMOS = Q(v) - Q(ref) + 5" in text
