"""``cgvq-analyze pilot``: one person's (or a few people's) ratings by distortion level, and
the design problems they show (levels the wrong way round, levels rated alike, a level
nobody saw, a narrow use of the scale), checked on ratings whose pattern the test sets."""

from __future__ import annotations

import pandas as pd
import pytest
from support.cli import analyze

from analysis.inputs import ratings_from_frame
from analysis.pilot_view import pilot_view
from analysis.synthetic import synthetic_study
from stimuli_manifests import save_manifest

from .conftest import write_session

# mean rating per (method, level); level 1 is meant to be the strongest
PATTERN = {("blur", 1): 20.0, ("blur", 2): 50.0, ("blur", 3): 80.0,  # as it should be
           ("noise", 1): 85.0, ("noise", 2): 60.0, ("noise", 3): 30.0,  # numbered backwards
           ("alias", 1): 88.0, ("alias", 2): 88.0, ("alias", 3): 88.0}  # never seen
REFERENCE = 90.0
JITTER = {1: -3.0, 2: 0.0, 3: 3.0}  # per repetition: averages to the pattern


def _ratings(pattern=PATTERN, reference=REFERENCE):
    st = synthetic_study(n_scenes=2, methods=("blur", "noise", "alias"), levels=3, n_raters=1,
                         noise_sd=0, bias_sd=0, seed=1)
    info = ratings_from_frame(st.ratings, st.manifest).stimuli
    frame = st.ratings.copy()
    frame["rating"] = [
        (reference if hidden else pattern[(info.at[s, "method"], int(info.at[s, "level"]))])
        + JITTER[int(rep)]
        for s, hidden, rep in zip(frame["stimulus"], frame["is_hidden_reference"],
                                  frame["repetition"], strict=True)]
    return st, frame


def test_the_levels_table_and_the_hints_follow_the_ratings():
    st, frame = _ratings()
    view = pilot_view(ratings_from_frame(frame, st.manifest))
    got = {(r.method, r.level): (r.mean, r.differential, r.ratings)
           for r in view.levels.itertuples()}
    for (method, level), mean in PATTERN.items():
        assert got[(method, level)] == pytest.approx((mean, REFERENCE - mean, 6))  # 2 x 3
    tests = view.stimuli[~view.stimuli["is_hidden_reference"]]
    assert (tests["differential"] == REFERENCE - tests["mean"]).all()
    hints = view.hints
    assert len(hints) == 3, hints
    assert hints[0].startswith("alias: levels 1 to 3 were rated alike (88 and 88)")
    assert hints[1].startswith("alias: even the strongest level (L1) was rated only 2 below")
    assert hints[2].startswith("noise: level 1 (meant to be the strongest) was rated 85 and "
                               "level 3 (the mildest) 30: the levels look numbered the wrong "
                               "way round")


def test_a_mild_level_far_from_the_reference_and_a_narrow_scale_are_named():
    st, frame = _ratings({**PATTERN, ("blur", 3): 40.0}, reference=90.0)
    hints = pilot_view(ratings_from_frame(frame, st.manifest)).hints
    assert "blur: even the mildest level (L3) was rated 50 below its reference: no level " \
           "comes near the threshold of visibility; consider a milder level" in hints
    narrow = pilot_view(ratings_from_frame(_ratings(
        {k: 45.0 + k[1] for k in PATTERN}, reference=44.0)[1], st.manifest)).hints
    assert "P01 used only 41-51 of the 0-100 scale: the briefing and the practice should " \
           "show the range of the distortions" in narrow
    assert any(h.startswith("P01 rated the hidden references 44 on average") for h in narrow)


def test_the_command_reads_one_pilots_session(tmp_path, capsys):
    """One rater is enough (report and dmos refuse it); the CSV holds each stimulus's mean
    rating and differential score as the pattern sets them."""
    st, frame = _ratings()
    manifest = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    frame = frame.sort_values(["repetition", "trial"]).reset_index(drop=True)
    session = write_session(tmp_path / "P01.sqlite", frame, study_id=st.manifest.manifest.study_id,
                            manifest_sha256=None,
                            settings={"timing_mode": "paced-pilot"},
                            display={"vsync": False, "refresh_hz": 60},
                            requeue=(3, 7), dropped={10: 2, 11: 5})
    out = tmp_path / "pilot.csv"
    code, stdout, err = analyze(capsys, "pilot", "--manifest", manifest, "--sessions", session,
                                "--out", out)
    assert code == 0, err
    assert "pilot of study synthetic: 1 rater, 60 ratings" in stdout
    assert "P01: 60 ratings" in stdout and "paced on the clock without vsync" in stdout
    # 62 presentations: the 2 re-queued attempts (which dropped frames) and 2 more with drops
    assert "dropped frames in 4 of 62 presentations (2 re-queued and shown again)" in stdout
    assert "  blur: L1 20 (70), L2 50 (40), L3 80 (10)" in stdout
    assert "look at: noise: level 1 (meant to be the strongest)" in stdout
    table = pd.read_csv(out, index_col="stimulus")
    tests = table[~table["is_hidden_reference"]]
    assert tests["P01"].tolist() == pytest.approx(
        [PATTERN[(m, int(lv))] for m, lv in zip(tests["method"], tests["level"], strict=True)])
    assert (tests["differential"] - (REFERENCE - tests["P01"])).abs().max() < 1e-9
    # report and dmos still refuse one rater, and point here
    code, _, err = analyze(capsys, "dmos", "--manifest", manifest, "--sessions", session,
                           "--out", tmp_path / "d.csv")
    assert code == 2 and "'cgvq-analyze pilot'" in err


@pytest.mark.parametrize(("args", "says"), [
    ([], "exactly one of --sessions, --ratings"),
    (["--out", "."], "is a folder"),
])
def test_bad_input_is_one_line(tmp_path, capsys, args, says):
    st, frame = _ratings()
    manifest = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    if args:
        frame.to_csv(tmp_path / "r.csv", index=False)
        args = ["--ratings", tmp_path / "r.csv", *args]
    code, _, err = analyze(capsys, "pilot", "--manifest", manifest, *args)
    assert code == 2 and err.count("\n") == 1 and says in err, err


def test_the_report_names_a_method_numbered_backwards(tmp_path):
    """Only `pilot` said it: a report (of two pilots, or of a study whose pilot was skipped)
    gave no word. Four raters rate the pattern; DMOS per level follows it exactly (the
    hidden reference is rated 90 throughout), so the report names noise, and only noise."""
    from analysis.pipeline import AnalysisConfig, run_analysis
    from analysis.report import summary, write_report

    st = synthetic_study(n_scenes=2, methods=("blur", "noise", "alias"), levels=3, n_raters=4,
                         noise_sd=0, bias_sd=0, seed=1)
    info = ratings_from_frame(st.ratings, st.manifest).stimuli
    frame = st.ratings.copy()
    rater_jitter = {r: 2.0 * k - 3.0 for k, r in enumerate(sorted(frame["participant"].unique()))}
    frame["rating"] = [
        (REFERENCE if hidden else PATTERN[(info.at[s, "method"], int(info.at[s, "level"]))])
        + JITTER[int(rep)] + rater_jitter[who]
        for s, hidden, rep, who in zip(frame["stimulus"], frame["is_hidden_reference"],
                                       frame["repetition"], frame["participant"], strict=True)]
    a = run_analysis(ratings_from_frame(frame, st.manifest),
                     AnalysisConfig(outliers="none", model="mos", n_boot=20, n_splits=20,
                                    ci_draws=4), progress=False)
    [hint] = summary(a)["reversed_levels"]
    # plain-mean DMOS = rating - hidden reference + 100: 85 -> 95, 30 -> 40
    assert hint.startswith("noise: DMOS falls from 95 at level 1 (meant to be the strongest "
                           "distortion) to 40 at level 3 (the mildest)")
    html = write_report(a, tmp_path / "report").read_text(encoding="utf-8")
    assert "noise: DMOS falls from 95 at level 1" in html
