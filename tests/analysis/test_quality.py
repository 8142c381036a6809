"""The data-quality section: what each participant's sessions say (vsync, timing mode,
pre-flight, dropped frames, re-queued trials, viewing time) and how they agree, with flags."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from analysis.inputs import load_ratings, ratings_from_frame
from analysis.pipeline import AnalysisConfig, run_analysis
from analysis.quality import THRESHOLDS, hidden_reference_mean, quality_table
from analysis.report import write_report
from analysis.synthetic import synthetic_study
from stimuli_manifests import load_manifest, save_manifest

from .conftest import write_session

pytest.importorskip("session_store")


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("quality")
    st = synthetic_study(n_scenes=3, methods=("blur", "noise"), levels=2, n_raters=6,
                         repetitions=2, noise_sd=5, seed=21)
    mpath = save_manifest(st.manifest.manifest, tmp / "manifest.json")
    sha = load_manifest(mpath).sha256
    folder = tmp / "sessions"
    folder.mkdir()
    special = {
        "P02": {"settings": {"timing_mode": "paced-pilot"}, "display": {"vsync": False}},
        "P03": {"preflight_skipped": True},
        "P04": {"requeue": (1, 4), "dropped": {k: 3 for k in range(0, 30, 2)}},
        "P05": {"viewing_ms": 400.0},
    }
    for rater, rows in st.ratings.groupby("participant"):
        write_session(folder / f"{rater}.sqlite", rows, study_id="synthetic",
                      manifest_sha256=sha, **special.get(rater, {}))
    # P02's pilot is kept (it would be left out beside the participants): its flags are read
    rs = load_ratings(mpath, sessions=[folder], include_pilots=True)
    a = run_analysis(rs, AnalysisConfig(model="mos", n_boot=50, n_splits=50), progress=False)
    return st, rs, a, tmp


def test_session_facts(analysed) -> None:
    st, _, a, _ = analysed
    q = a.quality
    n = len(st.ratings) // 6
    assert bool(q.loc["P01", "vsync"]) and not bool(q.loc["P02", "vsync"])
    assert q.loc["P02", "timing_mode"] == "paced-pilot"
    assert bool(q.loc["P03", "preflight_skipped"]) and not bool(q.loc["P01",
                                                                   "preflight_skipped"])
    assert q.loc["P04", "requeued"] == 2
    assert q.loc["P04", "presentations"] == n + 2  # two attempts re-queued, then answered
    # 15 rated attempts with 3 dropped frames each, plus the 2 re-queued attempts with 30
    assert q.loc["P04", "dropped_frames"] == 15 * 3 + 2 * 30
    assert q.loc["P04", "trials_with_drops"] == 15 + 2
    assert q.loc["P05", "median_viewing_s"] == pytest.approx(0.4)
    assert q.loc["P01", "median_viewing_s"] == pytest.approx(4.0)
    assert q.loc["P01", "median_toggles"] == 2
    assert (q["completeness"] == 1.0).all()


def test_flags_name_their_thresholds(analysed) -> None:
    _, _, a, _ = analysed
    flags = a.quality["flags"]
    assert "vsync off" in flags["P02"] and "paced-pilot" in flags["P02"]
    assert "pre-flight skipped" in flags["P03"]
    assert "2 trial(s) re-queued" in flags["P04"]
    assert f"> {THRESHOLDS['dropped_trials']:.0%}" in flags["P04"]
    assert f"< {THRESHOLDS['viewing_s']:g} s" in flags["P05"]
    assert flags["P01"] == ""


def test_report_shows_the_data_quality_section(analysed) -> None:
    _, _, a, tmp = analysed
    html = write_report(a, tmp / "report").read_text()
    section = html[html.index("id='quality'"):html.index("id='screening'")]
    for text in ("vsync off", "pre-flight skipped", "re-queued", "median viewing",
                 "paced-pilot"):
        assert text in section, text
    glance = html[html.index("At a glance"): html.index("</div>", html.index("At a glance"))]
    assert "data-quality flags" in glance and "P02" in glance


def test_agreement_figures_from_ratings_alone() -> None:
    st = synthetic_study(n_scenes=4, levels=2, n_raters=8, noise_sd=5, seed=3,
                         special={"Xinv": "inverted"})
    rs = ratings_from_frame(st.ratings, st.manifest)
    q = quality_table(rs)
    assert q.loc["Xinv", "loo_r"] < 0 and "r with all others" in q.loc["Xinv", "flags"]
    assert q.loc["Xinv", "hidden_ref_mean_share"] < THRESHOLDS["hidden_reference"]
    hid = hidden_reference_mean(rs)
    s = rs.raters.index("P01")
    refs = st.ratings[(st.ratings["participant"] == "P01") & st.ratings["is_hidden_reference"]]
    assert hid[s] == pytest.approx(refs["rating"].mean())
    assert np.isfinite(q["repeat_r"]).all()


def test_a_simulated_session_is_not_flagged_for_its_missing_pre_flight() -> None:
    from analysis.quality import rater_flags

    real = pd.Series({"preflight_skipped": True, "timing_mode": "vsync"})
    simulated = pd.Series({"preflight_skipped": True, "timing_mode": "simulated"})
    assert rater_flags(real, None) == ["pre-flight skipped"]
    assert rater_flags(simulated, None) == []
    # among real raters: flagged for what it is, never for a display check it had no display for
    assert rater_flags(simulated, None, simulated_among_real=True) == [
        "simulated rater (cgvq-study simulate; not a person)"]


def test_simulated_sessions_say_so_in_their_timing_mode() -> None:
    from analysis.sessions import Session
    from session_store.records import SessionInfo

    def session(settings: dict) -> Session:
        info = SessionInfo(**{**{f: None for f in SessionInfo.__dataclass_fields__},
                              "settings": settings})
        return Session(path="x.sqlite", info=info, ratings=[], presentations=[], n_planned=0)

    assert session({"simulated": True}).timing_mode == "simulated"
    assert session({"simulated": True, "timing_mode": "vsync"}).timing_mode == "vsync"
    assert session({}).timing_mode == ""
