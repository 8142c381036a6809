"""A participant whom the experimenter withdraws while they rate: the real app (under Xvfb,
through a real server) stops before the next trial with a screen that says the study has
ended for them, instead of asking for ratings nobody keeps and then telling them both to
continue and to send their file. Its screenshot is saved under
``test-artifacts/server/withdrawn-e2e/``."""

from __future__ import annotations

import shutil

import pytest
from support.gui import AppDriver
from support.studies import make_study

from .conftest import REPO, cli_env, run_cli

pytestmark = [pytest.mark.gui, pytest.mark.slow]  # 16 s: CI runs it after make test

ARTIFACTS = REPO / "test-artifacts" / "server" / "withdrawn-e2e"


def test_a_withdrawal_during_the_session_ends_it_on_the_participants_screen(
        tmp_path, xdisplay, invites, server_factory):
    study = make_study(tmp_path / "served", refs=2, min_display=(640, 480))  # 6 trials
    [inv] = invites(1, study=study)
    srv = server_factory(study)
    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    args = ["--server", srv.url, "--participant", "P01", "--token", inv.token, "--data-dir",
            str(tmp_path / "home"), "--seed", "5", "--practice", "0",
            "--max-dropped-frames", "-1", "--screenshots", str(ARTIFACTS), "--pilot-no-vsync"]
    env = {**xdisplay, **{k: v for k, v in cli_env().items() if k == "CGVQ_ADMIN_TOKEN"}}
    app = AppDriver(env, args)
    app.through_consent(timeout=90)
    app.rate()
    assert run_cli("withdraw", str(study), "P01").returncode == 0
    # the app learns of it with the next upload the server refuses (410), at the latest the
    # uploader's idle look (2 s) after the next rating; it then ends before the next trial
    ended = None
    for _ in range(4):
        line = app.wait("viewing", or_else=("server-ended",))
        if "server-ended" in line:
            ended = line
            break
        app.open_rating(min_view_s=2.5)
        app.key("Right", "Return")
        app.wait("recorded")
    assert ended is not None, app.lines[-10:]
    answered = int(ended.split("answered=")[1].split()[0])
    assert 1 <= answered < 6
    app.wait("ended-by-server")  # its screen
    app.key("Return")
    code, out = app.finish(timeout=60)
    assert code == 0, (out, app.lines[-10:])
    assert "no longer accepts answers from you" in out
    assert "run the same command again" not in out and "export" not in out
    assert (ARTIFACTS / "ended-by-server.png").exists()
