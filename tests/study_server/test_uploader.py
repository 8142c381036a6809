"""The upload thread as the app uses it: started before the session file exists, it follows
the file by itself; offline it backs off; the end-screen sentence says what arrived."""

from __future__ import annotations

import time

import pytest

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
        assert status.describe().startswith(
            "1 of your answers is not on the study server yet (the study server cannot be "
            "reached: "), status.describe()
        assert srv.url not in status.describe()  # no address, no errno for a participant
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
    offline = UploadStatus("offline", 3, 12, "cannot reach the study server "
                           "https://study.example.org:8443 (connection refused)",
                           pending=(("answer", 1), ("event", 2), ("rating", 6))).describe()
    assert offline == (
        "7 of your answers are not on the study server yet (the study server cannot be "
        "reached: connection refused). They are safe on this computer: start the study once "
        "more the same way when you are online (your invitation, or the command the "
        "experimenter gave you), and it sends only what is missing.")
    steps = UploadStatus("offline", 11, 12, "the study server answered 503",
                         pending=(("finish", 1),)).describe()
    assert steps.startswith("The last steps of your session are not on the study server yet "
                            "(the study server answered 503)")
    left = UploadStatus("offline", 3, 12, "cannot reach the study server http://x:1 (no "
                        "answer in time)", pending=(("rating", 2), ("withdrawn", 1)))
    assert left.describe().startswith(
        "Your withdrawal has not reached the study server yet (the study server cannot be "
        "reached: no answer in time). Please start the study once more the same way when "
        "you are online (your invitation, or the command the experimenter gave you): it only "
        "sends your withdrawal.")


def test_end_screen_text_with_and_without_everything_arrived(tmp_path):
    from study_app.screens import content

    keys = lambda screen, action: action.upper()  # noqa: E731
    path = tmp_path / "P01.sqlite"
    done = content.end(path, 12, False, keys, upload=(True, "All arrived."))
    assert "There is nothing to send" in done.body and "Send this one file" not in done.body
    missing = content.end(path, 12, False, keys, upload=(False, "3 of your answers are not"))
    assert "3 of your answers are not" in missing.body
    assert "## If you cannot start the study again" in missing.body  # the e-mail: a fallback
    assert "## Send this one file" not in missing.body
    plain = content.end(path, 12, False, keys)
    assert "Send this one file" in plain.body and "server" not in plain.body


@pytest.mark.slow  # about 7 s here: CI runs it after `make test` (.ci/run)
def test_the_count_left_comes_from_the_file_when_no_pass_succeeds(
        served_study, tmp_path, invites, server_factory):
    """A run that starts with the server down knows what earlier runs had sent: the answers
    still to send are those recorded since (before: every change of the session counted)."""
    [inv] = invites(1)
    srv = server_factory(served_study)
    path = tmp_path / "P01.sqlite"
    store = write_session(served_study, path, "P01", ratings=3)
    up = Uploader(path, ServerClient(srv.url, inv.token), "P01", idle_check_s=0.2).start()
    assert up.flush(30).all_arrived
    up.stop()
    srv.stop()
    for rating in (41.0, 42.0):  # two answers while the server is down
        nxt = store.next_trial()
        store.record(nxt.index, TrialResult(rating, 3000.0, 1, 1000.0, 2000.0, utc_now()))
    store.close()
    later = Uploader(path, ServerClient(srv.url, inv.token), "P01", min_backoff_s=5).start()
    try:
        status = later.flush(2.0)
    finally:
        later.stop()
    assert not status.all_arrived and status.acked_seq > 0
    assert status.describe().startswith("2 of your answers are not on the study server yet")
