"""Questionnaire answers and vision checks through the real server: uploaded with the ratings,
pulled (answers only when asked for), counted on the dashboard without ever showing an
answer, and refused when they are not answers to the study's questions."""

from __future__ import annotations

import csv
import json
import re
import time

import pytest
from support.sessions import session_entries

from session_store import SessionStore, read_session, utc_now
from session_store.answers import latest_answers
from session_store.protocol import PROTOCOL
from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest
from stimuli_manifests.panel_templates import default_panel
from study_app.remote import ServerClient, Uploader
from study_app.remote.admin import pull
from study_app.simulate import SimulationOptions, UploadOptions, run_simulation
from study_server.config import ServerConfig
from study_server.ingest import Refused
from study_server.state import ServerState

from .conftest import ADMIN, make_served_study, raw_request, run_cli, write_session

COMMENT = "<b>secret remark</b> about the videos"


def _with_panel(folder):
    study = make_served_study(folder)
    path = study / "manifest.json"
    data = json.loads(path.read_text())
    data["panel"] = default_panel()
    save_manifest(parse_manifest(data), path)
    save_manifest(fill_checksums(load_manifest(path)), path)
    return study


def test_answers_travel_with_the_ratings_and_stay_off_the_dashboard(tmp_path, invites,
                                                                    server_factory):
    study = _with_panel(tmp_path / "study")
    inv = invites(4, study=study)
    srv = server_factory(study, "--stats-every", "1")
    local = tmp_path / "local"
    result = run_simulation(study / "manifest.json", local,
                            SimulationOptions(raters=4, seed=2, colour_failures=1),
                            progress=False,
                            upload=UploadOptions(srv.url, {i.participant: i.token for i in inv},
                                                 timeout_s=120))
    assert all(s.all_arrived for s in result.upload.values()), result.upload

    pulled = pull(srv.url, ADMIN, tmp_path / "pulled", csv=tmp_path / "ratings.csv",
                  answers=tmp_path / "answers.csv")
    expected = {}
    for i in inv:
        rec = read_session(local / f"{i.participant}.sqlite")
        expected[i.participant] = {q: row["value"] for (_, q), row in
                                   latest_answers(rec.answers).items()}
    with open(tmp_path / "answers.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    got: dict[str, dict] = {}
    for r in rows:
        got.setdefault(r["participant"], {})[r["question"]] = json.loads(r["value"])
    assert got == {p: a for p, a in expected.items() if a}
    assert {r["format"] for r in rows} == {"cgvq-answers/1"}
    with open(tmp_path / "answers_screenings.csv", newline="") as fh:
        screenings = {r["participant"]: r["outcome"] for r in csv.DictReader(fh)}
    assert sorted(screenings.values()) == ["failed", "passed", "passed", "passed"]
    with open(tmp_path / "ratings.csv", newline="") as fh:
        header = next(csv.reader(fh))
    assert "question" not in header and "value" not in header  # answers stay apart
    by_pid = {s.participant: s for s in pulled.sessions}
    failed = next(p for p, o in screenings.items() if o == "failed")
    assert by_pid[failed].vision == {"colour": "failed"}
    assert by_pid[failed].n_answers == len(expected[failed])

    # one participant adds a comment with markup; the dashboard counts, never shows it
    pid = inv[0].participant
    with SessionStore.open(local / f"{pid}.sqlite") as store:
        store.record_answer("post_study", "comments", COMMENT, page=1)
    up = Uploader(local / f"{pid}.sqlite", ServerClient(srv.url, inv[0].token), pid).start()
    assert up.flush(60).all_arrived
    up.stop()
    _, headers, _ = raw_request(srv.url, "POST", "/dashboard/login",
                                     f"token={ADMIN}".encode(),
                                     {"Content-Type": "application/x-www-form-urlencoded"})
    cookie = headers["set-cookie"].split(";")[0]
    page = b""
    for _ in range(40):  # the statistics run in the background at most every second
        _, _, page = raw_request(srv.url, "GET", "/dashboard", headers={"Cookie": cookie})
        if re.search(rb'id="panel-answered">4<', page) and b"1 failed" in page:
            break
        time.sleep(0.25)
    assert re.search(rb'id="panel-answered">4<', page), page[:2000]
    assert b"1 failed" in page and b"colour failed" in page
    assert b"secret remark" not in page

    # a withdrawal deletes the answers with everything else
    res = run_cli("withdraw", str(study), failed)
    assert res.returncode == 0, res.stderr
    again = pull(srv.url, ADMIN, tmp_path / "pulled2", answers=tmp_path / "answers2.csv")
    assert failed not in {s.participant for s in again.sessions}
    with open(tmp_path / "answers2.csv", newline="") as fh:
        assert failed not in {r["participant"] for r in csv.DictReader(fh)}


@pytest.fixture
def state(tmp_path, invites, monkeypatch):
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    study = _with_panel(tmp_path / "study")
    invites(2, study=study)
    st = ServerState.open(ServerConfig(study, stats_in_background=False))
    yield st, study
    st.stop()


@pytest.mark.parametrize(("questionnaire", "question", "value", "says"), [
    ("demographics", "age", 7, "7 is outside 18..99"),
    ("demographics", "gender", "<script>", "is not one of female, male"),
    ("demographics", "shoe_size", 44, "has no question 'shoe_size'"),
    ("secret", "age", 30, "asks no questionnaire 'secret'"),
    ("post_study", "comments", "x" * 1_000_000, "1000000 characters; at most 500"),
    ("post_study", "comments", "bell\x07 " + COMMENT, "control character (U+0007)"),
])
def test_an_altered_client_cannot_upload_invalid_answers(state, tmp_path, questionnaire,
                                                          question, value, says):
    st, study = state
    path = tmp_path / "P01.sqlite"
    store = write_session(study, path, "P01", ratings=1)
    # the app would refuse this answer; an altered client writes it anyway
    store._change("answer", {"at": utc_now(), "questionnaire": questionnaire,
                             "question": question, "value": value, "page": 0, "ms": None})
    store.close()
    entries = session_entries(path)
    with pytest.raises(Refused) as info:
        st.ingest.upload("P01", {"protocol": PROTOCOL,
                                 "session_id": entries[0].body["header"]["session_id"],
                                 "client_time": utc_now(),
                                 "entries": [e.as_json() for e in entries]}, "127.0.0.1")
    assert info.value.status == 422 and says in info.value.detail
    assert st.store.session_of("P01") is None  # nothing of the upload was stored
    flags = st.store.flags("P01")
    assert flags and flags[0].kind == "answer"
    assert "secret remark" not in flags[0].message and "xxxxxxxx" not in flags[0].message
