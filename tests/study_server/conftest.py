"""Fixtures of the study-server tests: a servable study made on the fly and a real uvicorn
server in a subprocess on 127.0.0.1 (free port, bounded waits)."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest
from study_server.child import ServeProcess

REPO = Path(__file__).resolve().parents[2]
ADMIN = "test-admin-token-0123456789abcdef"
ARTIFACTS = REPO / "test-artifacts"


def make_served_study(folder: Path, *, refs: int = 2, conds: int = 2, repetitions: int = 2,
                      file_bytes: int = 4096, seed: int = 0, study_id: str = "served-study"
                      ) -> Path:
    """A study folder whose 'videos' are random bytes: the server never decodes, it serves
    files and checks checksums. ``refs * (1 + conds)`` stimuli (hidden references on)."""
    rng = np.random.default_rng(seed)
    videos = folder / "videos"
    videos.mkdir(parents=True, exist_ok=True)
    references, conditions = [], []
    methods = ("noise", "blur", "upscaling", "vrs")
    for r in range(refs):
        (videos / f"ref{r}.mkv").write_bytes(rng.bytes(file_bytes))
        references.append({"path": f"ref{r}.mkv", "scene": f"scene{r}"})
        for c in range(conds):
            name = f"ref{r}_c{c}.mkv"
            (videos / name).write_bytes(rng.bytes(file_bytes))
            conditions.append({"reference": f"SRC{r + 1:02d}", "method": methods[c % 2],
                               "level": c // 2 + 1, "path": name})
    manifest = parse_manifest({
        "study_id": study_id, "root": "videos",
        "protocol": {"repetitions": repetitions},
        "display": {"min_width": 640, "min_height": 480},
        "references": references, "conditions": conditions,
    })
    save_manifest(manifest, folder / "manifest.json")
    save_manifest(fill_checksums(load_manifest(folder / "manifest.json")),
                  folder / "manifest.json")
    (folder / "briefing.md").write_text("# Welcome\n\nRate the videos.\n", encoding="utf-8")
    (folder / "consent.md").write_text("I agree.\n", encoding="utf-8")
    return folder


def make_adaptive_study(folder: Path, settings: dict, *, refs: int = 3, conds: int = 3,
                        file_bytes: int = 256) -> Path:
    """:func:`make_served_study` with ``protocol.allocation: adaptive`` and ``settings``."""
    study = make_served_study(folder, refs=refs, conds=conds, repetitions=1,
                              file_bytes=file_bytes)
    path = study / "manifest.json"
    data = json.loads(path.read_text())
    data["protocol"].update({"allocation": "adaptive", "adaptive": settings})
    save_manifest(parse_manifest(data), path)
    save_manifest(fill_checksums(load_manifest(path)), path)
    return study


def adaptive_session(study: Path, folder: Path, participant: str, seed: int):
    """(schedule items, path, open store) of a started session of an adaptive study: block 1,
    every stimulus once in the seeded order, as the app plans it."""
    from session_store import SessionStore
    from session_store.schedule import make_schedule, schedule_items

    loaded = load_manifest(study / "manifest.json")
    items = schedule_items(loaded.manifest)
    path = folder / f"{participant}.sqlite"
    folder.mkdir(parents=True, exist_ok=True)
    store = SessionStore.create(
        path, participant=participant, study_id=loaded.manifest.study_id,
        manifest_sha256=loaded.sha256, seed=seed, app_version="test",
        plan=make_schedule(items, 1, seed), settings={"timing_mode": "vsync"})
    store.mark_started(display={"vsync": True})
    return items, path, store


def cli_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO)
    env["CGVQ_ADMIN_TOKEN"] = ADMIN
    return env


def RunningServer(study: Path, args: list[str] | None = None, port: int = 0) -> ServeProcess:
    """``cgvq-study serve`` of ``study`` in a child process with the tests' environment."""
    return ServeProcess(study, list(args or []), port=port, env=cli_env(), cwd=REPO)


def run_cli(*args: str, timeout: float = 300.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cgvq_cli.study_cli", *args], env=cli_env(),
                          capture_output=True, text=True, timeout=timeout, cwd=REPO)


@pytest.fixture
def served_study(tmp_path: Path) -> Path:
    return make_served_study(tmp_path / "study")


@pytest.fixture
def server_factory():
    """Start servers (stopped at the end of the test)."""
    started: list[RunningServer] = []

    def start(study: Path, *args: str, port: int = 0) -> RunningServer:
        srv = RunningServer(study, list(args), port).start()
        started.append(srv)
        return srv

    yield start
    for srv in started:
        srv.kill()


@pytest.fixture
def invites(served_study: Path, tmp_path: Path):
    """Invite participants into ``served_study`` (before serving): (participant, token)."""
    from session_store.invite import read_invites
    from study_server.operations import invite

    def make(n: int, server: str = "http://127.0.0.1:8000", prefix: str = "P",
             study: Path | None = None):
        out = tmp_path / f"invites-{prefix}-{time.monotonic_ns()}.csv"
        invite(study or served_study, n, out, prefix=prefix, server=server)
        return read_invites(out)

    return make


def write_session(study: Path, path: Path, participant: str, *, ratings: int,
                  finish: bool = False, seed: int = 1, clock=None):
    """A session file of ``study`` (as the app writes it) with ``ratings`` answered trials;
    ``clock`` (returning ISO times) stamps what follows the session's creation."""
    from session_store import SessionStore, TrialResult, utc_now
    from session_store.schedule import ScheduleItem, make_schedule
    from stimuli_manifests import load_manifest as _load

    loaded = _load(study / "manifest.json")
    m = loaded.manifest
    items = [ScheduleItem(s.id, s.reference, s.is_hidden_reference) for s in m.stimuli()]
    plan = make_schedule(items, m.protocol.repetitions, seed)
    store = SessionStore.create(path, participant=participant, study_id=m.study_id,
                                manifest_sha256=loaded.sha256, seed=seed, app_version="test",
                                plan=plan, settings={"timing_mode": "vsync"})
    if clock is not None:
        store.clock = clock
    store.save_preflight([{"name": "screen_size", "ok": True, "message": "ok"}],
                         skipped=False)
    store.log_event("consent", consent_sha256="c" * 64)
    store.mark_started(display={"vsync": True, "refresh_hz": 60.0})
    for i in range(ratings):
        store.record(plan[i].index, TrialResult(
            rating=10.0 + 3 * i, rt_ms=5000.0 + i, n_toggles=2, ms_on_reference=2000.0,
            ms_on_test=3000.0, presented_at=utc_now(), frames_presented=300,
            dropped_frames=i % 2, details={"vsync": True}))
    if finish:
        store.finish(allow_incomplete=True)
    return store


def raw_request(url: str, method: str, path: str, body: bytes | None = None,
                headers: dict[str, str] | None = None, timeout: float = 30.0
                ) -> tuple[int, dict[str, str], bytes]:
    """One HTTP request with the path sent exactly as given (no normalisation)."""
    import http.client
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=timeout)
    try:
        conn.putrequest(method, path, skip_accept_encoding=True)
        for k, v in (headers or {}).items():
            conn.putheader(k, v)
        if body is not None and "Content-Length" not in (headers or {}) and \
                "Transfer-Encoding" not in (headers or {}):
            conn.putheader("Content-Length", str(len(body)))
        conn.endheaders()
        if body is not None:
            # the server may answer early (e.g. 413) and close
            with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                conn.send(body)
        resp = conn.getresponse()
        headers_out = {k.lower(): v for k, v in resp.getheaders()}
        try:
            data = resp.read()
        except ConnectionResetError:  # answered (e.g. 400 for a bad Content-Length), then
            data = b""  # closed before the client read the body: the status is the answer
        return resp.status, headers_out, data
    finally:
        conn.close()


def db_dump(study: Path) -> dict[str, list[tuple]]:
    """Every row of the server database (read-only), to show that nothing was written."""
    import sqlite3

    con = sqlite3.connect(f"file:{study / 'server' / 'state.sqlite'}?mode=ro", uri=True)
    try:
        tables = [r[0] for r in con.execute(
            "SELECT name FROM sqlite_master WHERE type='table' AND name NOT LIKE 'sqlite_%'")]
        return {t: sorted(con.execute(f"SELECT * FROM {t}").fetchall(), key=repr)
                for t in tables}
    finally:
        con.close()


def replace_a_video(study: Path) -> None:
    """Version 2 of a served study: SRC01_HRC01 gets another video (same id, level 3), as
    before ``serve --new-version``."""
    path = study / "manifest.json"
    data = json.loads(path.read_text())
    for c in data["conditions"]:
        if c["id"] == "SRC01_HRC01":
            c.update(path="ref0_strong.mkv", level=3)
            c.pop("sha256", None)
    (study / "videos" / "ref0_strong.mkv").write_bytes(b"\x07" * 64)
    save_manifest(parse_manifest(data), path)
    save_manifest(fill_checksums(load_manifest(path)), path)
