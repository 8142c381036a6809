"""An adaptive study served again with ``--new-version`` while sessions run. Participants who
started on the first version finish on it: their later blocks come from that version's own
fits (they used to be refused with a 409, losing two thirds of the session). The new version
warms up on its own sessions, so its new stimuli are sampled (they used to be planned from
the old version's fit, which knows none of them), and the audit replays both versions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from support.sessions import session_entries

from session_store import TrialResult, utc_now
from session_store.protocol import PROTOCOL
from session_store.schedule import block_trials
from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest
from study_server.config import ServerConfig
from study_server.state import ServerState

from .conftest import ADMIN, adaptive_session, make_adaptive_study, run_cli

SETTINGS = {"blocks": 3, "warmup_participants": 2, "refit_seconds": 1, "bootstrap": 50}


def _adaptive_study(folder: Path) -> Path:
    return make_adaptive_study(folder, SETTINGS, refs=2, conds=2, file_bytes=64)


def _add_a_condition_per_scene(study: Path) -> set[str]:
    """Version 2: one more condition of each reference; the ids of the new stimuli."""
    path = study / "manifest.json"
    data = json.loads(path.read_text())
    before = {c["id"] for c in data["conditions"]}
    for r in range(2):
        (study / "videos" / f"ref{r}_new.mkv").write_bytes(bytes([r]) * 64)
        data["conditions"].append({"reference": f"SRC{r + 1:02d}", "method": "vrs",
                                   "level": 9, "path": f"ref{r}_new.mkv"})
    save_manifest(parse_manifest(data), path)
    save_manifest(fill_checksums(load_manifest(path)), path)
    after = {s.id for s in load_manifest(path).manifest.conditions}
    return after - before


class _Participant:
    def __init__(self, study: Path, folder: Path, pid: str, seed: int) -> None:
        self.pid = pid
        self.items, self.path, self.store = adaptive_session(study, folder, pid, seed)
        self.rng = np.random.default_rng(seed)

    def rate_and_upload(self, state: ServerState) -> None:
        for t in self.store.pending():
            self.store.record(t.index, TrialResult(
                rating=float(self.rng.uniform(20, 90)), rt_ms=3000.0, n_toggles=1,
                ms_on_reference=1000.0, ms_on_test=2000.0, presented_at=utc_now()))
        entries = session_entries(self.path)
        state.ingest.upload(self.pid, {
            "protocol": PROTOCOL, "session_id": self.store.info.session_id,
            "client_time": utc_now(), "entries": [e.as_json() for e in entries]}, None)

    def next_block(self, state: ServerState, block: int) -> list[str]:
        alloc = state.allocator_of(self.pid)
        issued = alloc.issue(self.pid, self.store.info.session_id, block,
                             self.store.plan()[-1].stimulus)
        self.store.add_block(block, issued.block_id,
                             block_trials(self.items, issued.stimuli, self.store.plan()),
                             issued_by="server")
        return issued.stimuli


def _open(study: Path, *, new_version: bool = False) -> ServerState:
    return ServerState.open(ServerConfig(study, stats_in_background=False,
                                         new_version=new_version))


def test_sessions_finish_on_their_version_and_the_new_one_adapts_on_its_own(
        tmp_path, invites, monkeypatch):
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", ADMIN)
    study = _adaptive_study(tmp_path / "adaptive")
    invites(4, study=study)
    sessions = tmp_path / "sessions"
    state = _open(study)
    p1, p2 = (_Participant(study, sessions, f"P0{k}", 10 + k) for k in (1, 2))
    for p in (p1, p2):
        p.rate_and_upload(state)
    v1_fit = state.allocator.refit()
    assert v1_fit is not None  # two sessions finished block 1: version 1 adapts
    p1.next_block(state, 2)
    p1.rate_and_upload(state)
    v1_ids = set(state.allocator.ids)
    state.stop()

    new = _add_a_condition_per_scene(study)
    state = _open(study, new_version=True)
    try:
        # P01 started on version 1 and finishes on it, planned from version 1's fit.
        block3 = p1.next_block(state, 3)
        assert set(block3) <= v1_ids
        v1 = state.allocator_of("P01")
        assert v1 is not state.allocator
        assert [b["fit_id"] for b in v1.log_rows() if b["participant"] == "P01"] == \
            [v1_fit, v1_fit]
        p1.rate_and_upload(state)
        # P03 on version 2: no fit of version 2 yet, so its block is uniform and holds the
        # new stimuli (version 1's fit knows none of them).
        p3 = _Participant(study, sessions, "P03", 13)
        p3.rate_and_upload(state)
        assert state.allocator.latest_fit() is None
        block2 = p3.next_block(state, 2)
        assert new <= set(block2)
        assert [b["fit_id"] for b in state.allocator.log_rows()] == [None]
    finally:
        state.stop()
    done = run_cli("allocation", str(study), "--replay")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "replayed 1 fit(s) and 3 block(s): identical" in done.stdout
    assert "(current)" in done.stdout
