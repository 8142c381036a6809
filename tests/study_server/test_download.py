"""Downloading a study from the server: size first, disk space, HTTP Range resume after a
cut, cache, sha256 refusal."""

from __future__ import annotations

import hashlib
import itertools
import re
import shutil
import socket
import threading
import time
from collections import namedtuple
from pathlib import Path

import pytest

from session_store.errors import StudyError
from study_app.remote import ServerClient, ServerUnavailable
from study_app.remote.download import check_disk_space, download_study, study_plan

from .conftest import make_served_study


class CuttingProxy:
    """Forwards one connection at a time to the server and cuts the response after
    ``limit`` bytes (a network that drops mid-download)."""

    def __init__(self, target_port: int, limit: int) -> None:
        self.limit = limit
        self.target = target_port
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(4)
        self.sock.settimeout(30)
        self.port = self.sock.getsockname()[1]
        self.ranges: list[str | None] = []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        for _ in range(40):  # bounded
            try:
                client, _ = self.sock.accept()
            except OSError:
                return
            upstream = socket.create_connection(("127.0.0.1", self.target), timeout=30)
            client.settimeout(30)
            request = client.recv(65536)
            m = re.search(rb"\r\nRange: bytes=(\d+)-", request, re.I)
            self.ranges.append(m.group(1).decode() if m else None)
            upstream.sendall(request)
            sent = 0
            while sent < self.limit:
                data = upstream.recv(min(65536, self.limit - sent))
                if not data:
                    break
                client.sendall(data)
                sent += len(data)
            upstream.close()
            client.shutdown(socket.SHUT_RDWR)
            client.close()

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def big_study(tmp_path):
    return make_served_study(tmp_path / "big", refs=1, conds=2, file_bytes=3 << 20)


def test_size_first_then_cut_download_resumes_with_range(big_study, tmp_path, invites,
                                                         server_factory):
    [inv] = invites(1, study=big_study)
    srv = server_factory(big_study)
    client = ServerClient(srv.url, inv.token)
    cache = tmp_path / "cache"
    plan = study_plan(client, "P01", cache)
    sizes = {f.path: f.size for f in plan.files}
    assert plan.missing_bytes() == plan.total_bytes == sum(sizes.values())
    assert {"manifest.json", "briefing.md", "consent.md", "videos/ref0.mkv"} <= set(sizes)
    need, free = check_disk_space(plan)
    assert need == plan.total_bytes and free > need
    # a network that drops every connection after 200 kB: each retry resumes where the last
    # one stopped (HTTP Range), until the retries are used up
    proxy = CuttingProxy(srv.port, 200_000)
    cut = ServerClient(f"http://127.0.0.1:{proxy.port}", inv.token)
    first_video = next(f for f in plan.files if f.path.startswith("videos/"))
    notices: list[str] = []
    with pytest.raises(ServerUnavailable, match="start again later to download the rest") as e:
        download_study(cut, "P01", plan, sleep=lambda s: None, notice=notices.append)
    proxy.close()
    # manifest, briefing and consent came whole: the message says they are kept
    assert f"3 of the {len(plan.files)} files are downloaded and kept" in str(e.value)
    # each retry is told in the participant's words, with no errno and no "start again"
    assert [n.rsplit("(", 1)[1] for n in notices] == [f"try {k} of 6)." for k in range(2, 7)]
    assert all(n.startswith("The download paused (the download of videos/") and
               "Errno" not in n and "start again" not in n for n in notices), notices
    part = plan.local(first_video).with_name(plan.local(first_video).name + ".part")
    got = part.stat().st_size
    video_ranges = proxy.ranges[3:]  # after manifest, briefing and consent
    assert video_ranges[0] is None and len(video_ranges) == 6
    offsets = [int(r) for r in video_ranges[1:]]
    assert offsets == sorted(offsets) and offsets[0] > 100_000  # each resumed further on
    assert offsets[-1] < got < first_video.size
    remaining = plan.missing_bytes()
    assert remaining == plan.total_bytes - got - sum(
        f.size for f in plan.files if f.path < first_video.path and plan.cached(f))
    progress: list[tuple[int, int]] = []
    folder = download_study(client, "P01", plan,
                            progress=lambda d, t, n: progress.append((d, t)))
    assert progress[-1] == (remaining, remaining)  # only what was missing moved
    # the bar moves at least every 64 KiB (on a slow line: every second or two)
    steps = [b[0] - a[0] for a, b in itertools.pairwise(progress)]
    assert max(steps) <= 1 << 16
    for f in plan.files:
        data = (folder / f.path).read_bytes()
        assert hashlib.sha256(data).hexdigest() == f.sha256
        assert data == (big_study / f.path).read_bytes()
    assert not list(folder.rglob("*.part"))
    # cached: nothing left to fetch, even with the server gone
    srv.kill()
    assert plan.missing() == [] and plan.missing_bytes() == 0
    download_study(ServerClient("http://127.0.0.1:9", inv.token), "P01", plan)


def test_a_file_that_does_not_match_its_checksum_is_refused(big_study, tmp_path, invites,
                                                            server_factory):
    [inv] = invites(1, study=big_study)
    srv = server_factory(big_study)
    client = ServerClient(srv.url, inv.token)
    plan = study_plan(client, "P01", tmp_path / "cache")
    victim = big_study / "videos" / "ref0_c1.mkv"
    data = bytearray(victim.read_bytes())
    data[1000] ^= 0xFF  # changed on the server after it started (same size)
    victim.write_bytes(bytes(data))
    with pytest.raises(StudyError, match="refused"):
        download_study(client, "P01", plan)
    local = plan.local(next(f for f in plan.files if f.path.endswith("ref0_c1.mkv")))
    assert not local.exists() and not local.with_name(local.name + ".part").exists()


def test_not_enough_disk_space_stops_before_anything_is_written(big_study, tmp_path, invites,
                                                                server_factory, monkeypatch):
    [inv] = invites(1, study=big_study)
    srv = server_factory(big_study)
    plan = study_plan(ServerClient(srv.url, inv.token), "P01", tmp_path / "cache")
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10 << 30, 10 << 30, 5 << 20))
    with pytest.raises(StudyError, match=r"needs 9\.\d MB more disk space, but only 5\.2 MB"):
        check_disk_space(plan)
    assert not (tmp_path / "cache").exists()


def test_study_plan_refuses_a_hostile_file_list(tmp_path):
    class Fake(ServerClient):
        def __init__(self, files):
            super().__init__("http://127.0.0.1:9", "t" * 20)
            self.files = files

        def json(self, method, path, payload=None):
            return {"study_id": "s", "manifest_sha256": "a" * 64, "files": self.files}

    for bad in ("../x", "/etc/passwd", "a/../../b", "a\\b", ""):
        files = [{"path": "manifest.json", "size": 1, "sha256": "a" * 64},
                 {"path": bad, "size": 1, "sha256": "b" * 64}]
        with pytest.raises(StudyError, match="file"):
            study_plan(Fake(files), "P01", tmp_path)
    assert not any(Path(tmp_path).iterdir())


def test_fetch_study_shows_the_size_and_falls_back_to_the_downloaded_copy(
        served_study, tmp_path, invites, server_factory):
    from study_app.remote.participant import fetch_study

    [inv] = invites(1)
    srv = server_factory(served_study)
    said: list[str] = []
    first = fetch_study(inv.__class__(srv.url, "P01", inv.token), tmp_path / "data",
                        say=said.append, progress=False)
    assert not first.offline and (first.folder / "manifest.json").is_file()
    assert said[0] == f"Connecting to the study server {srv.url} ..."  # at once, before any wait
    assert "to download" in said[1] and "free on this disk" in said[1]
    assert first.sessions_dir == first.folder.parent / "sessions"
    again = fetch_study(inv.__class__(srv.url, "P01", inv.token), tmp_path / "data",
                        say=said.append, progress=False)
    assert "already on this computer" in said[-1] and again.folder == first.folder
    srv.kill()
    offline = fetch_study(inv.__class__(srv.url, "P01", inv.token), tmp_path / "data",
                          say=said.append, progress=False)
    assert offline.offline and offline.folder == first.folder
    assert said[-1].startswith("The study server cannot be reached: ") and \
        "The study downloaded before is used" in said[-1] and srv.url not in said[-1]
    with pytest.raises(ServerUnavailable, match="the server may be down or this computer "
                       r"offline; try again later \(anything downloaded so far is kept\)") as e:
        fetch_study(inv.__class__(srv.url, "P01", inv.token), tmp_path / "other",
                    say=said.append, progress=False)  # nothing downloaded before: no start
    assert "Errno" not in str(e.value) and "connection refused" in str(e.value)


@pytest.mark.slow  # about 9 s here: CI runs it after `make test` (.ci/run)
def test_a_rate_limited_download_waits_and_completes(tmp_path, invites, server_factory):
    study = make_served_study(tmp_path / "many", refs=3, conds=3, file_bytes=2048)  # 15 files
    [inv] = invites(1, study=study)
    srv = server_factory(study, "--rate", "4", "--burst", "3")
    client = ServerClient(srv.url, inv.token)
    plan = study_plan(client, "P01", tmp_path / "cache")
    waits: list[float] = []

    def sleep(s: float) -> None:
        waits.append(s)
        time.sleep(s)

    folder = download_study(client, "P01", plan, sleep=sleep)
    assert waits and all(w >= 1 for w in waits)  # the server's Retry-After was honoured
    assert plan.missing() == [] and (folder / "videos" / "ref2_c2.mkv").is_file()


def test_a_downloaded_file_damaged_since_is_fetched_again(served_study, tmp_path, invites,
                                                          server_factory):
    """A mark written at download time vouched for the file whenever its size matched, so a
    byte changed later was never fetched again and every run failed its pre-flight."""
    from study_app.remote.participant import fetch_study

    [inv] = invites(1)
    srv = server_factory(served_study)
    said: list[str] = []
    invite = inv.__class__(srv.url, "P01", inv.token)
    first = fetch_study(invite, tmp_path / "data", say=said.append, progress=False)
    video = sorted(first.folder.rglob("*.mkv"))[0]
    good = video.read_bytes()
    damaged = bytearray(good)
    damaged[len(good) // 2] ^= 0xFF
    video.write_bytes(bytes(damaged))  # same size, other content
    said.clear()
    again = fetch_study(invite, tmp_path / "data", say=said.append, progress=False)
    assert again.folder == first.folder
    assert "checking the files already on this computer" in said[1]
    assert "to download" in said[2], said
    assert hashlib.sha256(video.read_bytes()).digest() == hashlib.sha256(good).digest()


def test_a_wrong_token_says_what_to_check(served_study, tmp_path, invites, server_factory):
    from study_app.remote import ServerRefused
    from study_app.remote.participant import fetch_study

    [inv] = invites(1)
    srv = server_factory(served_study)
    with pytest.raises(ServerRefused, match=r"the invitation .* the experimenter sent you") as e:
        fetch_study(inv.__class__(srv.url, "P01", "x" * 43), tmp_path / "data",
                    say=lambda _: None, progress=False)
    assert e.value.status == 403


def test_a_served_run_checks_its_files_once(served_study, tmp_path, invites, server_factory,
                                            monkeypatch):
    """The download hashed every file (or downloaded and checked it); the pre-flight then
    read them all a second time. It now compares the download's sha256s, and a file the
    download vouched for with another sha256 than the manifest's is still a finding."""
    from types import SimpleNamespace

    import stimuli_manifests.manifest_io as manifest_io
    from cgvq_cli.study_cli import main as study
    from session_store.study_folder import load_study
    from study_app import app
    from study_app.preflight import check_checksums
    from study_app.remote.participant import fetch_study

    [inv] = invites(1)
    srv = server_factory(served_study)
    invite = inv.__class__(srv.url, "P01", inv.token)
    for attempt in ("downloaded", "cached"):
        remote = fetch_study(invite, tmp_path / "data", say=lambda _: None, progress=False)
        on_disk = {p.resolve() for p in remote.folder.rglob("*") if p.is_file()}
        assert set(remote.verified_sha256) == on_disk, attempt
        assert all(hashlib.sha256(p.read_bytes()).hexdigest() == h
                   for p, h in remote.verified_sha256.items())
    loaded = load_study(remote.folder)
    read: list[Path] = []
    real = manifest_io.sha256_path
    monkeypatch.setattr(manifest_io, "sha256_path", lambda p: read.append(p) or real(p))
    check = check_checksums(loaded, from_server=True, known_sha256=remote.verified_sha256)
    assert check.ok and check.value["files"] == len(on_disk) - 1 and read == []  # manifest
    video = sorted(remote.folder.rglob("*.mkv"))[0].resolve()
    wrong = {**remote.verified_sha256, video: "0" * 64}
    check = check_checksums(loaded, from_server=True, known_sha256=wrong)
    assert not check.ok and "downloaded again" in check.message and read == []
    plain = check_checksums(loaded, from_server=True)  # without them: every file read
    assert plain.ok and len(read) == plain.value["files"] - plain.value["unverified"] > 0

    seen: list = []

    def fake_run(_study, opts):
        seen.append(opts)
        return SimpleNamespace(status="closed", answered=0, total=0, session_path=None)

    monkeypatch.setattr(app, "run_study", fake_run)
    code = study(["run", "--server", srv.url, "--participant", "P01", "--token", inv.token,
                  "--data-dir", str(tmp_path / "data")])
    assert code == 1 and set(seen[0].files_verified) == on_disk
