"""The dashboard's statistics after ``serve --new-version``: only sessions of the version now
served count, as the report refuses the others under this manifest. Version 2 replaces the
video of SRC01_HRC01 (same id, a stronger distortion); the old video's ratings used to be
averaged into its DMOS, and the old raters counted towards the target."""

from __future__ import annotations

from pathlib import Path

import pytest
from support.sessions import session_entries

from analysis.inputs import load_ratings
from session_store import TrialResult, utc_now
from session_store.protocol import PROTOCOL
from stimuli_manifests import load_manifest
from study_server.config import ServerConfig
from study_server.operations import invite
from study_server.state import ServerState

from .conftest import make_served_study, replace_a_video, write_session


def _rate(state: ServerState, study: Path, folder: Path, pid: str, seed: int,
          value: dict[str, float]) -> None:
    store = write_session(study, folder / f"{pid}.sqlite", pid, ratings=0, seed=seed)
    for t in store.pending():
        rating = 95.0 if t.is_hidden_reference else value.get(t.stimulus, 50.0)
        store.record(t.index, TrialResult(rating=rating + seed % 3, rt_ms=3000.0, n_toggles=1,
                                          ms_on_reference=1000.0, ms_on_test=2000.0,
                                          presented_at=utc_now()))
    store.finish()
    sid = store.info.session_id
    store.close()
    entries = session_entries(folder / f"{pid}.sqlite")
    state.ingest.upload(pid, {"protocol": PROTOCOL, "session_id": sid, "client_time": utc_now(),
                              "entries": [e.as_json() for e in entries]}, None)


def test_the_dashboard_counts_only_the_version_now_served(tmp_path):
    study = make_served_study(tmp_path / "study", refs=2, conds=2, repetitions=1, file_bytes=64)
    invite(study, 6, tmp_path / "invites.csv", server="http://127.0.0.1:8000")
    sessions = tmp_path / "sessions"
    sessions.mkdir()
    state = ServerState.open(ServerConfig(study, stats_in_background=False))
    for k, pid in enumerate(("P01", "P02", "P03")):
        _rate(state, study, sessions, pid, 10 + k, {"SRC01_HRC01": 80.0})
    state.stop()

    replace_a_video(study)
    state = ServerState.open(ServerConfig(study, new_version=True, stats_in_background=False))
    try:
        for k, pid in enumerate(("P04", "P05", "P06")):
            _rate(state, study, sessions, pid, 20 + k, {"SRC01_HRC01": 20.0})
        snap = state.stats.refresh(force=True)
        html = state.pages.dashboard()
    finally:
        state.stop()
    # What the report will use under this manifest: the version-2 raters only.
    report = load_ratings(study / "manifest.json", sessions=[sessions])
    assert report.raters == ["P04", "P05", "P06"]
    assert snap.study.n_raters == 3 and snap.other_versions == 3
    assert snap.per_stimulus["SRC01_HRC01"] == 3
    dmos = snap.study.dmos.set_index("stimulus")["dmos"] if "stimulus" in \
        snap.study.dmos.columns else snap.study.dmos["dmos"]
    # rated 20-22 against hidden references at 95-97: DMOS about 100 - 75 = 25, not the
    # 55 of a pool with the old video's 80s
    assert abs(float(dmos["SRC01_HRC01"]) - 25.0) < 3.0
    assert "3 participant(s) rated an earlier version" in html


# about 10 s: CI runs it after `make test` (.ci/run), as `make test-slow` does
@pytest.mark.slow
def test_pull_saves_each_versions_manifest_to_analyse_its_sessions_with(
        tmp_path, served_study, invites, server_factory):
    import hashlib

    from study_app.remote.admin import manifest_name, pull
    from study_app.simulate import SimulationOptions, UploadOptions, run_simulation

    from .conftest import ADMIN

    study = served_study
    tokens = {i.participant: i.token for i in invites(4)}
    first = dict(list(tokens.items())[:2])
    v1 = load_manifest(study / "manifest.json").sha256
    srv = server_factory(study)
    run_simulation(study / "manifest.json", tmp_path / "local1",
                   SimulationOptions(raters=2, seed=1), progress=False,
                   upload=UploadOptions(srv.url, first, timeout_s=120))
    srv.stop()
    replace_a_video(study)
    v2 = load_manifest(study / "manifest.json").sha256
    srv = server_factory(study, "--new-version")
    rest = {p: t for p, t in tokens.items() if p not in first}
    run_simulation(study / "manifest.json", tmp_path / "local2",
                   SimulationOptions(raters=2, seed=2, participant_prefix="P"), progress=False,
                   upload=UploadOptions(srv.url, rest, timeout_s=120))
    pulled = tmp_path / "pulled"
    result = pull(srv.url, ADMIN, pulled)
    assert set(result.manifests) == {v1, v2}
    for sha, path in result.manifests.items():
        assert path == pulled / manifest_name(sha)
        assert hashlib.sha256(path.read_bytes()).hexdigest() == sha
    old = load_ratings(result.manifests[v1], sessions=[pulled])
    assert old.raters == sorted(first)
    new = load_ratings(study / "manifest.json", sessions=[pulled])
    assert new.raters == sorted(rest)
    refusal = next(x for x in new.exclusions if x.kind == "refused session")
    assert manifest_name(v1) in refusal.reason
