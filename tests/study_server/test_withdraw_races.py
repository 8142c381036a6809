"""A withdrawal that races other work on a running server: a pull that is under way when
someone withdraws keeps no copy of them and does not stop with a 404; an upload whose flag
lands after the withdrawal leaves no flag row (``test_storage.py``)."""

from __future__ import annotations

import csv

from study_app.remote import ServerClient, sync_session
from study_app.remote import admin as admin_module

from .conftest import ADMIN, db_dump, run_cli, write_session


def test_a_withdrawal_during_a_pull_leaves_no_copy_and_no_abort(
        served_study, tmp_path, invites, server_factory, monkeypatch):
    inv = invites(3)
    srv = server_factory(served_study)
    for i in inv:
        path = tmp_path / f"{i.participant}.sqlite"
        write_session(served_study, path, i.participant, ratings=3).close()
        assert sync_session(path, ServerClient(srv.url, i.token), i.participant)
    fetch = admin_module._entries

    def withdrawing(client, pid):
        if pid == "P02":  # withdraws after the listing, before their entries are fetched
            assert run_cli("withdraw", str(served_study), "P02").returncode == 0
        entries = fetch(client, pid)
        if pid == "P01":  # withdraws after their entries were fetched
            assert run_cli("withdraw", str(served_study), "P01").returncode == 0
        return entries

    monkeypatch.setattr(admin_module, "_entries", withdrawing)
    out = tmp_path / "pulled"
    result = admin_module.pull(srv.url, ADMIN, out, csv=tmp_path / "r.csv")
    assert [s.participant for s in result.sessions] == ["P03"]
    assert set(result.withdrawn) == {"P01", "P02"}
    assert sorted(p.name for p in out.glob("*.sqlite")) == ["P03.sqlite"]
    with open(tmp_path / "r.csv", newline="") as f:
        assert {row["participant"] for row in csv.DictReader(f)} == {"P03"}
    assert {t[0] for t in db_dump(served_study)["tombstones"]} == {"P01", "P02"}


def test_a_participant_withdrawn_during_the_session_is_told_it_ended(served_study, tmp_path,
                                                                    invites, server_factory,
                                                                    capsys):
    """Their app kept going, and at the end they read both "run the same command again to
    continue" and "send your session file": the two things the withdrawal rules out."""
    from pathlib import Path

    from cgvq_cli.study_commands.run import _report
    from session_store import TrialResult, utc_now
    from study_app.app import RunOutcome
    from study_app.remote import ServerClient
    from study_app.remote.uploader import Uploader

    from .conftest import run_cli, write_session

    [inv] = invites(1)
    srv = server_factory(served_study)
    path = tmp_path / "P01.sqlite"
    store = write_session(served_study, path, "P01", ratings=2)
    up = Uploader(path, ServerClient(srv.url, inv.token), "P01", idle_check_s=0.2).start()
    assert up.flush(20).all_arrived
    assert run_cli("withdraw", str(served_study), "P01").returncode == 0
    nxt = store.next_trial()  # the participant rates on: that upload is refused
    store.record(nxt.index, TrialResult(40.0, 4000.0, 1, 1000.0, 3000.0, utc_now()))
    store.close()
    up.notify()
    status = up.flush(20)
    up.stop()
    assert status.state == "refused" and status.withdrawn
    assert _report(RunOutcome("quit", Path(path), 3, 6), status) == 0
    out = capsys.readouterr().out
    assert "no longer accepts answers" in out and "nothing more to do" in out
    assert "run the same command again" not in out and "export" not in out


def test_an_adaptive_block_is_not_asked_for_a_withdrawn_participant():
    """The block request flushes the uploads first; a refused (withdrawn) uploader used to
    read as "the server cannot be reached", and the app offered to try again."""
    import pytest

    from study_app.remote import ServerRefused
    from study_app.remote.participant import request_block
    from study_app.remote.uploader import WITHDRAWN, UploadStatus

    class Refused:
        def flush(self, timeout):
            return UploadStatus("refused", 3, 4, error="gone", withdrawn=True)

    class NoClient:
        def json(self, *a, **k):
            raise AssertionError("no block request for a withdrawn participant")

    with pytest.raises(ServerRefused) as caught:
        request_block(NoClient(), "P01", Refused(), "sid", 2, None)
    assert caught.value.status == 410 and str(caught.value) == WITHDRAWN
