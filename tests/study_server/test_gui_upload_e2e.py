"""The real app under Xvfb downloads its study from a real server and uploads as it rates:
``cgvq-study run --server URL --participant ID --token T`` end to end, driven by X input
(the driver in tests/support/gui.py), in a process where the research stack cannot be
imported. The end screen says everything arrived; the server's copy equals the local file."""

from __future__ import annotations

import shutil

import pytest
from support.gui import AppDriver
from support.sessions import session_tables
from support.studies import make_study

from session_store import verify_session
from study_app.remote.admin import pull

from .conftest import ADMIN, REPO, cli_env, run_cli

pytestmark = pytest.mark.gui

ARTIFACTS = REPO / "test-artifacts" / "server" / "app-e2e"


@pytest.mark.slow  # about 15 s here: CI runs it after `make test` (.ci/run)
def test_the_app_downloads_and_uploads_to_the_server(tmp_path, xdisplay, invites,
                                                     server_factory):
    study = make_study(tmp_path / "served", min_display=(640, 480))  # 3 stimuli, 64x64, 1 s
    [inv] = invites(1, study=study)
    srv = server_factory(study)
    data = tmp_path / "participant-home"
    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    args = ["--server", srv.url, "--participant", "P01", "--token", inv.token, "--data-dir",
            str(data), "--seed", "5", "--practice", "0", "--max-dropped-frames", "-1",
            "--screenshots", str(ARTIFACTS), "--pilot-no-vsync"]
    env = {**xdisplay, **{k: v for k, v in cli_env().items() if k == "CGVQ_ADMIN_TOKEN"}}
    app = AppDriver(env, args)
    app.wait("preflight-passed", timeout=90)  # after the download
    app.key("space")
    app.wait("welcome")
    app.key("space")
    app.wait("consent")
    app.key("a")
    for _ in range(3):
        app.wait("viewing")
        app.open_rating()
        app.key("Right", "Right", "Return")
        app.wait("recorded")
    app.wait("uploaded arrived=1", timeout=60)
    app.wait("end")
    app.key("Return")
    code, out = app.finish(timeout=60)
    assert code == 0, (out, app.lines[-10:])
    assert "Session finished: 3 trials. All your answers have arrived" in out
    assert "to download;" in out and "free on this disk" in out  # size and space, first

    local = next(data.rglob("sessions/P01.sqlite"))
    assert verify_session(local).complete
    pulled = pull(srv.url, ADMIN, tmp_path / "pulled")
    assert [s.report.state for s in pulled.sessions] == ["complete"]
    assert session_tables(tmp_path / "pulled" / "P01.sqlite") == session_tables(local)
    assert (ARTIFACTS / "end.png").is_file()
    # the same command again: the session is finished, nothing to run, everything arrived
    again = run_cli("run", *args[:8])
    assert again.returncode == 0, again.stderr
    assert "Your session is finished" in again.stdout and "have arrived" in again.stdout


@pytest.mark.slow  # about 9 s here: CI runs it after `make test` (.ci/run)
def test_run_from_a_server_refuses_clearly(tmp_path, served_study, invites, server_factory):
    [inv] = invites(1)
    srv = server_factory(served_study)
    proc = run_cli("run", "--server", srv.url, "--participant", "P01", "--token",
                   "wrong-token-0000000000", "--data-dir", str(tmp_path / "d"))
    assert proc.returncode == 2 and "403" in proc.stderr and proc.stderr.count("\n") == 1
    proc = run_cli("run", "--server", "http://127.0.0.1:9", "--participant", "P01", "--token",
                   inv.token, "--data-dir", str(tmp_path / "d"))
    assert proc.returncode == 2 and "cannot reach" in proc.stderr
    proc = run_cli("run", str(served_study), "--server", srv.url, "--token", inv.token)
    assert proc.returncode == 2 and "not both" in proc.stderr
    proc = run_cli("run", "--server", srv.url, "--participant", "P01")
    assert proc.returncode == 2 and "--token" in proc.stderr
