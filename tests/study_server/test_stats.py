"""The dashboard's statistics: computed in the background at most every N seconds, from what
arrived, through the analysis package; equal to the analysis run on the pulled files."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from session_store import utc_now
from session_store.outbox import read_entries
from session_store.protocol import PROTOCOL
from session_store.schema import open_existing
from study_app.simulate import SimulationOptions, run_simulation
from study_server.config import ServerConfig
from study_server.state import ServerState

from .conftest import ADMIN, make_served_study, write_session


def _upload_file(st: ServerState, path, pid: str) -> None:
    con = open_existing(path, readonly=True)
    entries = read_entries(con)
    con.close()
    sid = entries[0].body["header"]["session_id"]
    for k in range(0, len(entries), 150):
        st.ingest.upload(pid, {"protocol": PROTOCOL, "session_id": sid,
                               "client_time": utc_now(),
                               "entries": [e.as_json() for e in entries[k:k + 150]]}, None)


@pytest.fixture
def panel(tmp_path, invites, monkeypatch):
    """6 simulated raters (one inverted outlier) written locally, not uploaded yet."""
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    study = make_served_study(tmp_path / "s", refs=3, conds=3, repetitions=2, file_bytes=64)
    invites(6, study=study)
    run_simulation(study / "manifest.json", tmp_path / "local",
                   SimulationOptions(raters=6, outliers=1, outlier_kind="inverted", seed=4,
                                     participant_prefix="P"), progress=False)
    return study, tmp_path / "local"


def test_statistics_match_the_analysis_of_the_same_ratings(panel):
    from analysis import load_ratings, screen_raters
    from analysis.reliability import reliability

    study, local = panel
    st = ServerState.open(ServerConfig(study, stats_in_background=False))
    try:
        files = sorted(local.glob("P*.sqlite"))
        for f in files:
            _upload_file(st, f, f.stem)
        snap = st.stats.refresh()
    finally:
        st.stop()
    rs = load_ratings(study / "manifest.json", sessions=files)
    screened = rs.with_raters(screen_raters(rs).kept)
    expected = reliability(screened).icc["ICC(2,k)"]
    assert snap.study is not None and snap.study.icc2k == pytest.approx(expected, abs=1e-9)
    assert snap.n_ratings == rs.n_ratings == 6 * 24
    assert set(snap.study.removed) == set(rs.raters) - set(screened.raters)
    assert snap.per_stimulus and set(snap.per_stimulus.values()) == {12}
    outlier = snap.study.removed[0]
    assert snap.participants[outlier].panel_r < 0 < min(
        p.panel_r for pid, p in snap.participants.items() if pid != outlier)
    d = snap.study.dmos
    assert len(d) == 12 and (d["ci95_low"] <= d["dmos"]).all()
    assert snap.figures["dmos"][:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow  # about 9 s here: CI runs it after `make test` (.ci/run)
def test_recomputed_at_most_every_n_seconds_and_only_on_change(panel):
    study, local = panel
    st = ServerState.open(ServerConfig(study, stats_every_s=2.0))
    st.start()
    try:
        files = sorted(local.glob("P*.sqlite"))
        for f in files[:4]:
            _upload_file(st, f, f.stem)
        st.stats.poke()
        deadline = time.monotonic() + 60
        while st.stats.snapshot().computed_at is None and time.monotonic() < deadline:
            time.sleep(0.05)
        first = st.stats.snapshot()
        assert first.n_ratings == 4 * 24
        t_first = time.monotonic()
        _upload_file(st, files[4], files[4].stem)
        for _ in range(20):  # a burst of uploads and page views
            st.stats.poke()
            st.pages.dashboard()
            time.sleep(0.02)
        if time.monotonic() - t_first < 1.5:
            assert st.stats.snapshot() is first  # not yet: at most every 2 s
        while st.stats.snapshot() is first and time.monotonic() < deadline:
            time.sleep(0.05)
        second = st.stats.snapshot()
        assert second.n_ratings == 5 * 24
        time.sleep(2.5)  # nothing changed: nothing recomputed
        assert st.stats.snapshot() is second
    finally:
        st.stop()


def test_the_dashboard_frame_holds_the_exported_rows(tmp_path: Path):
    """The server's tidy rows of the uploaded entries equal the session file's own export."""
    from session_store import read_info, read_session
    from study_server.stats import ratings_frame

    study = make_served_study(tmp_path / "study")
    path = tmp_path / "P01.sqlite"
    write_session(study, path, "P01", ratings=4).close()
    info = read_info(path)
    con = open_existing(path, readonly=True)
    try:
        entries = read_entries(con)
    finally:
        con.close()
    rows = [("P01", info.manifest_sha256 or "", e.kind, json.dumps(e.body), info.session_id)
            for e in entries]
    frame = ratings_frame(rows, info.study_id)
    exported = read_session(path).ratings
    assert len(exported) == 4
    assert frame.to_dict("records") == [dict(r) for r in exported]


def test_live_statistics_leave_out_withdrawals_and_count_the_raters_behind_them(
        tmp_path, invites, monkeypatch):
    """Five finished raters; P06 rates 12 of 18 trials and withdraws in the app; P07 has
    rated 4 (below half). The analysis of the same files uses P01..P05 only: so must the live
    statistics, the ratings count a target is judged on, and the rater count the stopping
    rule records. The withdrawal used to count (140 of 120 usable ratings in the audit)."""
    from analysis import load_ratings

    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    study = make_served_study(tmp_path / "s", refs=3, conds=2, repetitions=2, file_bytes=64)
    invites(7, study=study)
    local = tmp_path / "local"
    run_simulation(study / "manifest.json", local,
                   SimulationOptions(raters=5, seed=4, participant_prefix="P"), progress=False)
    store = write_session(study, local / "P06.sqlite", "P06", ratings=12)
    store.withdraw()
    store.close()
    write_session(study, local / "P07.sqlite", "P07", ratings=4).close()
    st = ServerState.open(ServerConfig(study, stats_in_background=False))
    try:
        for f in sorted(local.glob("P*.sqlite")):
            _upload_file(st, f, f.stem)
        snap = st.stats.refresh()
        widths = st.store.width_history()
        page = st.pages.context()
        html = st.pages.dashboard()
    finally:
        st.stop()
    # The page's counts agree: P06's ratings are shown apart, P06 counts as withdrawn, and
    # the target per stimulus expects the six who may still rate, not seven.
    assert page["n_arrived"] == 5 * 18 + 4 and page["n_arrived_withdrawn"] == 12
    assert page["n_withdrawn"] == page["n_withdrew_in_app"] == 1
    # the page says their data are still stored, and how to delete them
    note = html.split('id="withdrew-in-app">', 1)[1].split("</p>", 1)[0]
    assert "data still stored: P06." in note and "cgvq-study withdraw STUDY ID" in note
    assert snap.target_per_stimulus == 6 * 2
    finished = sorted(local.glob("P0[1-5].sqlite"))
    rs = load_ratings(study / "manifest.json", sessions=finished)
    assert rs.n_ratings == 5 * 18
    assert snap.n_ratings == 5 * 18 + 4  # P07's ratings arrived; P06's are withdrawn
    assert snap.study.n_raters == 5 and snap.study.n_ratings == 5 * 18
    assert snap.study.n_partial == 1  # P07, below half of their trials
    row = html.split('data-participant="P07"', 1)[1].split("</tr>", 1)[0]
    assert "partial: not used yet" in row and "keep" not in row
    assert [w[:2] for w in widths] == [(5, 5 * 18)]


def test_invites_beside_a_running_server_move_the_target_without_an_upload(
        served_study, invites, monkeypatch):
    """``invite`` writes into the database the server has open: the dashboard's target per
    stimulus follows at the next statistics turn, not only after the next upload."""
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    invites(2)
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    try:
        reps = json.loads((served_study / "manifest.json").read_text())["protocol"][
            "repetitions"]
        assert st.stats.refresh().target_per_stimulus == 2 * reps
        invites(3, prefix="Q")
        assert st.stats.refresh().target_per_stimulus == 5 * reps
    finally:
        st.stop()
