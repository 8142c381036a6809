"""The real app in an adaptive study (Xvfb, X input, research stack unimportable): block 1
from the session's seed, block 2 from the server, then the server goes away at the end of
block 2, the app says so and offers to retry, the server comes back, the retry brings
block 3. The session holds every block the server issued, in its chain, and the server's
copy equals the local file."""

from __future__ import annotations

import json
import shutil

import pytest
from support.gui import AppDriver
from support.sessions import session_tables
from support.studies import make_study

from session_store import read_session, verify_session
from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest
from study_app.remote.admin import pull

from .conftest import ADMIN, REPO, cli_env

# about 35 s: CI runs it after `make test` (.ci/run), as does `make test-slow`
pytestmark = [pytest.mark.gui, pytest.mark.slow]

ARTIFACTS = REPO / "test-artifacts" / "server" / "app-adaptive"


def test_the_app_gets_its_blocks_from_the_server_and_rides_out_an_outage(
        tmp_path, xdisplay, invites, server_factory):
    study = make_study(tmp_path / "served", min_display=(640, 480))  # 3 stimuli
    path = study / "manifest.json"
    data = json.loads(path.read_text())
    data["protocol"].update({"allocation": "adaptive",
                             "adaptive": {"blocks": 3, "block_trials": 2,
                                          "warmup_participants": 2}})
    save_manifest(parse_manifest(data), path)
    save_manifest(fill_checksums(load_manifest(path)), path)
    [inv] = invites(1, study=study)
    srv = server_factory(study)
    home = tmp_path / "participant-home"
    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    args = ["--server", srv.url, "--participant", "P01", "--token", inv.token, "--data-dir",
            str(home), "--seed", "5", "--practice", "0", "--max-dropped-frames", "-1",
            "--screenshots", str(ARTIFACTS), "--pilot-no-vsync"]
    env = {**xdisplay, **{k: v for k, v in cli_env().items() if k == "CGVQ_ADMIN_TOKEN"}}
    app = AppDriver(env, args)
    app.through_consent(timeout=90)  # after the download
    app.rate(3)  # block 1: every stimulus once
    app.wait("block number=2 trials=2 issued_by=server", timeout=60)
    app.rate(1)
    srv.kill()  # the server goes away before block 3 is asked for
    app.rate(1)
    app.wait("block-unavailable", timeout=90)
    srv.start()
    app.key("Return")  # try again
    app.wait("block number=3 trials=2 issued_by=server", timeout=90)
    app.rate(2)
    app.wait("uploaded arrived=1", timeout=60)
    app.wait("end")
    app.key("Return")
    code, out = app.finish(timeout=60)
    assert code == 0, (out, app.lines[-10:])
    assert "Session finished: 7 trials" in out

    local = next(home.rglob("sessions/P01.sqlite"))
    record = read_session(local)
    assert verify_session(local).complete and len(record.ratings) == 7
    blocks = [e for e in record.events if e["kind"] == "block"]
    assert [(b["block"], b["issued_by"], b["trials"]) for b in blocks] == \
        [(2, "server", 2), (3, "server", 2)]
    pulled = pull(srv.url, ADMIN, tmp_path / "pulled")
    assert [s.report.state for s in pulled.sessions] == ["complete"]
    assert session_tables(tmp_path / "pulled" / "P01.sqlite") == session_tables(local)
    assert (ARTIFACTS / "block-unavailable.png").is_file()
