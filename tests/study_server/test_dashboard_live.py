"""What the dashboard says between statistics runs: the manifest's plan from the first
request on, a pace that follows the clock (not the last computation), and an empty study
that is not 'done'."""

from __future__ import annotations

import json
import re
from datetime import datetime, timedelta

import study_server.dashboard as dashboard
import study_server.stats as stats
from study_app.remote import ServerClient, sync_session
from study_server.config import ServerConfig
from study_server.state import ServerState

from .conftest import ADMIN, write_session


def _text(html: str) -> str:
    return " ".join(re.sub(r"<[^>]+>", " ", html).split())


def _later(hours: float):
    """A ``datetime`` whose now() is ``hours`` ahead (the dashboard's clock, patched)."""
    class Later(datetime):  # the real one: a patched module's would add up
        @classmethod
        def now(cls, tz=None):
            return super().now(tz) + timedelta(hours=hours)

    return Later


def test_the_plan_is_shown_before_the_first_statistics(served_study, invites, monkeypatch):
    """A restarted server showed '0 / 0' trials, no 'to go' and no questionnaire columns for
    up to --stats-every seconds, until its first computation."""
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    invites(2)
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    try:
        page = st.pages.context()
        html = _text(st.pages.dashboard())
    finally:
        st.stop()
    planned = page["snap"].planned_per_participant
    assert page["snap"].computed_at is None and planned > 0
    assert page["n_to_go"] == 2 * planned
    assert f"0 / {planned}" in html and "0 / 0" not in html
    assert page["snap"].target_per_stimulus > 0 and "0 below target" not in html


def test_the_pace_follows_the_clock_and_a_pause_says_stalled(served_study, tmp_path, invites,
                                                             server_factory, monkeypatch):
    """The rate and the time to completion were computed with the statistics, which run
    only when the data changes: hours after the last upload they still promised minutes."""
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    [inv] = invites(1)
    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, "P01", ratings=4).close()
    srv = server_factory(served_study)
    sync_session(path, ServerClient(srv.url, inv.token), "P01")
    srv.stop()
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    try:
        st.stats.refresh()
        now = _text(st.pages.dashboard())
        assert st.stats.rate_per_hour() > 0 and "estimated time to completion" in now
        monkeypatch.setattr(stats, "datetime", _later(hours=2))  # two hours without an upload
        monkeypatch.setattr(dashboard, "datetime", _later(hours=2))
        later = st.pages.context()
        html = _text(st.pages.dashboard())
    finally:
        st.stop()
    assert later["rate_per_hour"] == 0 and later["eta_hours"] is None
    assert f"stalled no ratings given in the last hour, {later['n_to_go']} to go" in html
    assert "running, no contact for 2.0 h" in html  # the participant a reminder may help
    assert "1 participant to look at" in html and "P01 : no contact for 2.0 h" in html


def test_an_empty_study_is_not_done(served_study, monkeypatch):
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    try:
        st.stats.refresh()
        html = _text(st.pages.dashboard())
    finally:
        st.stop()
    assert "done" not in html
    assert "no participants invited yet ( cgvq-study invite )" in html


def test_the_list_to_look_at_says_why_in_words():
    """Each marked cell and flag of a row, as a reason; nothing for a clean row or for a
    participant who withdrew in the app (none of their data is used)."""
    ps = stats.ParticipantStats("P03", timing="paced-60", dropped_frames=4, requeued=1,
                                preflight_skipped=True, panel_r=0.31,
                                vision={"ishihara": "failed", "acuity": "passed"},
                                unreadable=1)
    flag = {"kind": "clock_skew", "count": 2, "message": "..."}
    late = {"kind": "offline_gap", "count": 1, "message": "..."}
    row = {"p": {"participant": "P03", "last_seen": None, "flags": [flag, late]}, "ps": ps,
           "state": "running", "stalled": False}
    limits = stats.CellLimits(panel_r=0.75, hidden_reference=50.0)
    ps.hidden_reference_mean = 42.0
    assert dashboard.attention(row, partial=True, limits=limits) == [
        "partial: not used yet", "failed the ishihara check", "r panel 0.31",
        "hidden references rated 42.0 on average",
        "timing paced-60", "4 dropped frame(s)", "1 re-queued trial(s)",
        "pre-flight skipped", "1 unreadable entry"]  # words, not the flags' codes
    # a clock the server corrected and answers that arrived late after rating offline were
    # handled: in the flags table, not in the list (at 30+ participants they drowned it)
    clean = stats.ParticipantStats("P04", timing="vsync", panel_r=0.8, hidden_reference_mean=51,
                                   vision={"ishihara": "passed"}, preflight_skipped=False)
    assert dashboard.attention({**row, "ps": clean, "p": {**row["p"], "flags": []}},
                               partial=False, limits=limits) == []
    assert dashboard.attention({**row, "state": "withdrew in app"}, partial=True,
                               limits=limits) == []
    # on a lower-is-better scale a hidden reference rated high is the one to look at
    flipped = stats.CellLimits(hidden_reference=3.0, higher_is_better=False)
    assert flipped.hidden_reference_low(4.2) and not flipped.hidden_reference_low(1.5)


def test_the_marks_use_the_report_thresholds_on_the_study_scale(served_study):
    """The page marked r panel below 0.5 while the report flags below 0.75, and never marked
    a low hidden-reference mean: both now mark what the report flags."""
    from types import SimpleNamespace

    from analysis.quality import THRESHOLDS

    manifest = json.loads((served_study / "manifest.json").read_text())
    plan = stats.study_plan(SimpleNamespace(manifest_bytes=json.dumps(manifest).encode()))
    assert plan.limits == stats.CellLimits(THRESHOLDS["loo_r"], 50.0, True)
    manifest["scale"] = {"min": 1, "max": 5, "direction": "lower_is_better", "labels": []}
    plan = stats.study_plan(SimpleNamespace(manifest_bytes=json.dumps(manifest).encode()))
    assert plan.limits.hidden_reference == 3.0 and not plan.limits.higher_is_better


def test_a_participant_who_fetched_the_study_is_seen_before_any_session(
        served_study, tmp_path, invites, server_factory, monkeypatch):
    """A download stuck halfway or a pre-flight that failed leaves no session on the server;
    the download itself says the participant was there, and when last."""
    from study_app.remote.download import study_plan

    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    p01, _ = invites(2)
    srv = server_factory(served_study)
    client = ServerClient(srv.url, p01.token)
    plan = study_plan(client, "P01", tmp_path / "data")  # GET /study
    with client.open("GET", f"/api/v1/participants/P01/files/{plan.files[0].path}") as resp:
        resp.read()
    srv.stop()
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    try:
        rows = {r["p"]["participant"]: r for r in st.pages.context()["rows"]}
        html = _text(st.pages.dashboard())
        monkeypatch.setattr(dashboard, "datetime", _later(hours=1))  # still no session
        later = {r["p"]["participant"]: r for r in st.pages.context()["rows"]}
    finally:
        st.stop()
    assert rows["P01"]["state"] == dashboard.FETCHED and rows["P01"]["p"]["last_seen"]
    assert rows["P02"]["state"] == "invited" and not rows["P02"]["p"]["last_seen"]
    assert "seen, no session yet" in html
    assert later["P01"]["stalled"] and not later["P02"]["stalled"]
    assert later["P01"]["attention"][0].startswith(
        "got the study 60 min ago but no session arrived: the display check may have failed")
    assert later["P01"]["urgency"] == dashboard.LOOK_NOW
    assert later["P02"]["attention"] == []


def test_a_participant_who_stopped_to_continue_later_is_told_apart(
        served_study, tmp_path, invites, server_factory, monkeypatch):
    """"Stop and continue later" is the last thing the app sends (a quit event): the row says
    so, not "running" (which an app that lost its connection also shows)."""
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    p01, p02 = invites(2)
    srv = server_factory(served_study)
    for inv, stop in ((p01, True), (p02, False)):
        path = tmp_path / f"{inv.participant}.sqlite"
        store = write_session(served_study, path, inv.participant, ratings=2)
        if stop:
            store.log_event("quit", answered=2)
        store.close()
        sync_session(path, ServerClient(srv.url, inv.token), inv.participant)
    srv.stop()
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    try:
        rows = {r["p"]["participant"]: r for r in st.pages.context()["rows"]}
        html = _text(st.pages.dashboard())
    finally:
        st.stop()
    assert rows["P01"]["state"] == dashboard.STOPPED == "stopped, to continue later"
    assert rows["P02"]["state"] == "running"
    assert "stopped, to continue later" in html


def test_the_pace_counts_ratings_when_given_not_when_they_arrive(
        served_study, tmp_path, invites, server_factory, monkeypatch):
    """Answers rated offline a day ago and sent in one burst read as 20 ratings/h, and the
    page promised a completion time when nobody had rated for 20 hours."""
    from session_store.records import utc_now

    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    [inv] = invites(1)
    path = tmp_path / "P01.sqlite"
    day_ago = (stats.datetime.now(stats.UTC) - timedelta(hours=20)).isoformat(
        timespec="milliseconds").replace("+00:00", "Z")
    write_session(served_study, path, "P01", ratings=6, clock=lambda: day_ago).close()
    srv = server_factory(served_study)
    sync_session(path, ServerClient(srv.url, inv.token), "P01")  # its clock is right now
    srv.stop()
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    try:
        arrived = st.store.ratings_received_since(utc_now()[:10])  # all 6 arrived today
        page = st.pages.context()
        html = _text(st.pages.dashboard())
    finally:
        st.stop()
    assert len(arrived) == 6
    assert page["rate_per_hour"] == 0 and page["eta_hours"] is None
    assert "stalled no ratings given in the last hour" in html


def test_what_is_still_to_come_is_split_by_who_owes_it():
    """'198 to go' at 34 ratings/h read as 5.8 h, though only 14 belonged to people rating:
    the card now says who owes the rest."""
    def row(state, planned, n, stalled=False):
        s = None if n is None else {"n_ratings": n}
        return {"state": state, "s": s, "planned": planned, "stalled": stalled}

    rows = [row("running", 24, 10), row("running", 24, 20), row("running", 24, 4, True),
            row(dashboard.STOPPED, 24, 6), row(dashboard.FETCHED, 0, None),
            row("invited", 0, None), row("finished", 24, 24), row("withdrew in app", 24, 3)]
    to_go = dashboard._to_go(rows, 24)
    assert to_go == {"rating now": (14 + 4, 2), "stopped": (20 + 18, 2),
                     "not started": (48, 2)}
    assert dashboard._to_go_words(to_go) == (
        "18 from the 2 participants rating now, 38 from 2 who stopped or went quiet, "
        "48 from 2 not started")
    assert dashboard._to_go_words({"rating now": (7, 1)}) == (
        "7 from the 1 participant rating now")


def test_stopped_came_back_and_refused_rows_in_the_list(served_study, tmp_path, invites,
                                                        server_factory, monkeypatch):
    """A stopped participant is reminded of after a day, not after 15 min; one whose app came
    back but sent nothing (a failed display check) is the first to look at; a refused upload
    the app then sent again is no longer a reason."""
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    p01, p02, p03 = invites(3)
    srv = server_factory(served_study)
    for inv in (p01, p02, p03):
        path = tmp_path / f"{inv.participant}.sqlite"
        store = write_session(served_study, path, inv.participant, ratings=3)
        if inv is not p03:
            store.log_event("quit", answered=3)
        store.close()
        sync_session(path, ServerClient(srv.url, inv.token), inv.participant)
    srv.stop()
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    try:
        sess = {p: st.store.session_of(p) for p in ("P01", "P02", "P03")}
        back = (stats.parse_time(sess["P02"].last_received) + timedelta(minutes=30))
        st.store.touch("P02", back.isoformat().replace("+00:00", "Z"), None)
        before = (stats.parse_time(sess["P03"].last_received) - timedelta(seconds=5))
        after = (stats.parse_time(sess["P03"].last_received) + timedelta(seconds=5))
        st.store.add_flag("P03", sess["P03"].session_id, "refused", "upload refused: entry 4 "
                      "where 3 was expected", before.isoformat().replace("+00:00", "Z"))

        monkeypatch.setattr(dashboard, "datetime", _later(hours=2))
        rows = {r["p"]["participant"]: r for r in st.pages.context()["rows"]}
        html = _text(st.pages.dashboard())
        assert not rows["P01"]["stalled"] and rows["P01"]["attention"] == []  # 2 h: not yet
        assert rows["P02"]["came_back"] and rows["P02"]["urgency"] == dashboard.LOOK_NOW
        assert rows["P02"]["attention"][0].startswith("came back 1.5 h ago but sent nothing")
        assert "stopped, to continue later; came back 1.5 h ago, nothing arrived since" in html
        assert rows["P03"]["attention"] == ["no contact for 2.0 h"]  # the refusal resolved
        st.store.add_flag("P03", sess["P03"].session_id, "refused", "upload refused: again",
                      after.isoformat().replace("+00:00", "Z"))
        rows = {r["p"]["participant"]: r for r in st.pages.context()["rows"]}
        assert rows["P03"]["attention"] == ["no contact for 2.0 h",
                                            "an upload refused, nothing accepted since"]
        look = [r["p"]["participant"] for r in st.pages.context("look")["rows"]]
        assert look[:2] == ["P02", "P03"]  # the one who needs help before the reminders

        monkeypatch.setattr(dashboard, "datetime", _later(hours=25))
        rows = {r["p"]["participant"]: r for r in st.pages.context()["rows"]}
    finally:
        st.stop()
    assert rows["P01"]["stalled"] and rows["P01"]["attention"] == [
        "stopped 25.0 h ago, not back since"]


def test_a_row_says_when_its_statistics_are_older_than_its_trials(served_study, tmp_path,
                                                                   invites, monkeypatch):
    """Trials and state are live, the columns from s/trial to screening come from the last
    statistics run: a row whose trials arrived after it says how many those columns saw."""
    from session_store import TrialResult, utc_now
    from session_store.outbox import read_entries
    from session_store.protocol import PROTOCOL
    from session_store.schema import open_existing

    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    invites(1)
    path = tmp_path / "P01.sqlite"
    store = write_session(served_study, path, "P01", ratings=3)
    st = ServerState.open(ServerConfig(served_study, stats_in_background=False))
    sent = 0

    def upload() -> None:
        nonlocal sent
        con = open_existing(path, readonly=True)
        entries = read_entries(con)
        con.close()
        st.ingest.upload("P01", {"protocol": PROTOCOL, "client_time": utc_now(),
                                 "session_id": entries[0].body["header"]["session_id"],
                                 "entries": [e.as_json() for e in entries[sent:]]}, None)
        sent = len(entries)

    try:
        upload()
        st.stats.refresh()
        fresh = _text(st.pages.dashboard())
        plan = store.plan()
        for i in range(3, 5):  # two more trials arrive before the next statistics run
            store.record(plan[i].index, TrialResult(
                rating=40.0, rt_ms=5000.0, n_toggles=2, ms_on_reference=2000.0,
                ms_on_test=3000.0, presented_at=utc_now(), frames_presented=300,
                dropped_frames=0, details={"vsync": True}))
        upload()
        behind = _text(st.pages.dashboard())
        st.stats.refresh()
        caught_up = _text(st.pages.dashboard())
    finally:
        store.close()
        st.stop()
    assert st.stats.snapshot().participants["P01"].n_ratings == 5
    assert "statistics: first" not in fresh and "statistics: first" not in caught_up
    assert "5 / " in behind and "statistics: first 3" in behind
