"""The upload thread as the app uses it: started before the session file exists, it follows
the file by itself; offline it backs off; the end-screen sentence says what arrived."""

from __future__ import annotations

import time

from session_store import TrialResult, utc_now
from study_app.remote import ServerClient, Uploader, UploadStatus

from .conftest import write_session


def test_uploader_waits_for_the_file_and_follows_it_without_notify(
        served_study, tmp_path, invites, server_factory):
    [inv] = invites(1)
    srv = server_factory(served_study)
    path = tmp_path / "P01.sqlite"
    up = Uploader(path, ServerClient(srv.url, inv.token), "P01", idle_check_s=0.2).start()
    try:
        time.sleep(0.5)
        assert up.status.state == "starting"  # no file yet: nothing sent, no error
        store = write_session(served_study, path, "P01", ratings=2)
        for _ in range(3):  # the app commits ratings and never calls notify()
            nxt = store.next_trial()
            store.record(nxt.index, TrialResult(40.0, 3000.0, 1, 1000.0, 2000.0, utc_now()))
        deadline = time.monotonic() + 30
        while not up.status.all_arrived and time.monotonic() < deadline:
            time.sleep(0.1)
        assert up.status.all_arrived and up.status.state == "up to date"
        assert srv_session_ratings(srv, served_study) == 5
        srv.stop()  # offline: the app keeps writing, the uploader backs off
        nxt = store.next_trial()
        t0 = time.perf_counter()
        store.record(nxt.index, TrialResult(41.0, 3000.0, 1, 1000.0, 2000.0, utc_now()))
        assert time.perf_counter() - t0 < 1.0  # a commit never waits for the network
        deadline = time.monotonic() + 30
        while up.status.state != "offline" and time.monotonic() < deadline:
            time.sleep(0.1)
        status = up.flush(0.5)
        assert status.state == "offline" and not status.all_arrived
        assert "1 recorded step of your session (an answer or your progress) has not " \
               "reached the study server" in status.describe()
        store.close()
    finally:
        up.stop()


def srv_session_ratings(srv, study) -> int:
    from .conftest import db_dump

    return db_dump(study)["sessions"][0][9]  # n_ratings


def test_end_screen_sentences():
    assert UploadStatus("up to date", 12, 12).describe() == (
        "All your answers have arrived at the study server.")
    refused = UploadStatus("refused", 3, 12, "409: entry 4 differs").describe()
    assert "refused the upload" in refused and "cgvq-study export" in refused
    offline = UploadStatus("offline", 3, 12, "cannot reach").describe()
    assert offline.startswith("9 recorded steps of your session (answers and progress) have "
                              "not reached")
    assert "sent the next time you start the study the same way" in offline


def test_end_screen_text_with_and_without_everything_arrived(tmp_path):
    from study_app.screens import content

    keys = lambda screen, action: action.upper()  # noqa: E731
    path = tmp_path / "P01.sqlite"
    done = content.end(path, 12, False, keys, upload=(True, "All arrived."))
    assert "There is nothing to send" in done.body and "Send this one file" not in done.body
    missing = content.end(path, 12, False, keys, upload=(False, "3 change(s) have not ..."))
    assert "3 change(s) have not" in missing.body and "Send this one file" in missing.body
    plain = content.end(path, 12, False, keys)
    assert "Send this one file" in plain.body and "server" not in plain.body
