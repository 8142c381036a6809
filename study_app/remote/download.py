"""Downloading a study from its server: manifest, texts and videos, resumable and checked.

:func:`study_plan` asks the server which version of the study this participant runs and
which files it needs; :meth:`DownloadPlan.missing_bytes` is what remains to fetch (files
already in the cache with the right sha256 are kept: each is hashed once per run, so a file
damaged since it was downloaded is fetched again), so the app can show the size and check
free disk space (:func:`check_disk_space`) before anything is written. :func:`download_study`
then fetches each missing file into ``<name>.part``; a download cut off mid-file resumes with
an HTTP ``Range`` request from where it stopped. Every finished file is checked against the
sha256 the server listed (and the manifest's own sha256 against the version's); a mismatch
deletes the file and refuses.
"""

from __future__ import annotations

import hashlib
import logging
import re
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import quote

from session_store.errors import StudyError
from session_store.protocol import participant_path
from stimuli_manifests.paths import portable_part_problem

from .http import ServerClient, ServerUnavailable, plain_reason

log = logging.getLogger(__name__)

CHUNK = 1 << 20
NET_CHUNK = 1 << 16
"""Network reads: at most 64 KiB, handed on as soon as they arrive, so that the progress bar
moves (and a stall loses little) on a slow line."""
DISK_MARGIN_BYTES = 200 * 1024 * 1024
"""Free space kept beyond the download (session file, decoded frames spilled by the OS)."""

Progress = Callable[[int, int, str], None]
"""``progress(bytes_done, bytes_total, file_name)`` during a download."""


@dataclass(frozen=True)
class RemoteFile:
    path: str
    """Relative to the study folder, POSIX separators."""
    size: int
    sha256: str


@dataclass(frozen=True)
class DownloadPlan:
    """The study version a participant runs and where its files go."""

    study_id: str
    manifest_sha256: str
    files: tuple[RemoteFile, ...]
    folder: Path
    """``<cache>/<study_id>/<manifest sha256 prefix>``: the local study folder."""
    _verified: dict[str, bool] = field(default_factory=dict, compare=False, repr=False)
    """Per listed path: whether the local copy matched, hashed once per plan (one run)."""

    @property
    def total_bytes(self) -> int:
        return sum(f.size for f in self.files)

    def local(self, f: RemoteFile) -> Path:
        """Where ``f`` goes; never outside :attr:`folder` (checked again after joining)."""
        dest = self.folder.joinpath(*PurePosixPath(_safe_relative(f.path)).parts)
        if not dest.resolve().is_relative_to(self.folder.resolve()):
            raise StudyError(f"the study server listed a file outside the study folder: "
                             f"{f.path[:100]!r}")
        return dest

    def cached(self, f: RemoteFile) -> bool:
        """Present with the right size and sha256. Hashed, not taken from a mark written at
        download time: damage that keeps the size (a disk error, a sync tool) was never seen,
        and every later run failed its pre-flight with no way to fetch the file again."""
        if f.path not in self._verified:
            p = self.local(f)
            try:
                ok = p.stat().st_size == f.size and _sha256(p) == f.sha256
            except OSError:
                ok = False
            self._verified[f.path] = ok
        return self._verified[f.path]

    def verified(self, f: RemoteFile) -> None:
        """``f`` was just downloaded and checked."""
        self._verified[f.path] = True

    def verified_sha256(self) -> dict[Path, str]:
        """Resolved path to sha256 of every file hashed (or downloaded and checked) in this
        run and found right: the pre-flight compares these instead of reading them again."""
        return {self.local(f).resolve(): f.sha256 for f in self.files
                if self._verified.get(f.path)}

    def missing(self) -> list[RemoteFile]:
        return [f for f in self.files if not self.cached(f)]

    def missing_bytes(self) -> int:
        """Bytes still to download (partial downloads counted as what they lack)."""
        total = 0
        for f in self.missing():
            part = _part(self.local(f))
            have = part.stat().st_size if part.is_file() else 0
            total += max(f.size - have, 0) if have <= f.size else f.size
        return total


def _part(p: Path) -> Path:
    return p.with_name(p.name + ".part")


def _sha256(p: Path) -> str:
    digest = hashlib.sha256()
    with open(p, "rb") as fh:
        while chunk := fh.read(CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def _safe_part(part: str) -> bool:
    """One path segment that means the same file on every OS (the manifest's own rule,
    :func:`stimuli_manifests.paths.portable_part_problem`)."""
    return portable_part_problem(part) is None


def _safe_relative(text: Any) -> str:
    """A listed file path, refused unless it stays inside the study folder on any OS."""
    if not isinstance(text, str) or not text or len(text) > 1000:
        raise StudyError(f"the study server listed an invalid file name {str(text)[:100]!r}")
    if text.startswith("/") or not all(_safe_part(p) for p in text.split("/")):
        raise StudyError("the study server listed a file outside the study folder or with "
                         f"characters a file name cannot hold: {text[:100]!r}")
    return text


def _remote_file(f: Any) -> RemoteFile:
    """One listed file: a safe path, a size of 0 or more, a sha256 of 64 hex digits."""
    size, sha = int(f["size"]), str(f["sha256"])
    if size < 0 or re.fullmatch(r"[0-9a-f]{64}", sha) is None:
        raise StudyError(f"the study server listed {str(f['path'])[:100]!r} with an invalid "
                         "size or sha256")
    return RemoteFile(_safe_relative(f["path"]), size, sha)


def study_plan(client: ServerClient, participant: str, cache: str | Path) -> DownloadPlan:
    """Ask the server which study version and files this participant needs."""
    info = client.json("GET", participant_path(participant, "study"))
    try:
        study_id = str(info["study_id"])
        sha = str(info["manifest_sha256"])
        files = tuple(_remote_file(f) for f in info["files"])
    except (KeyError, TypeError, ValueError):
        raise StudyError("the study server's file list is malformed") from None
    from session_store.ids import check_participant_id

    try:
        check_participant_id(study_id)
    except StudyError:
        raise StudyError(f"the study server names an invalid study id {study_id!r}") from None
    if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
        raise StudyError("the study server sent an invalid manifest checksum")
    if "manifest.json" not in {f.path for f in files}:
        raise StudyError("the study server's file list lacks manifest.json")
    folder = Path(cache) / study_id / sha[:16]
    return DownloadPlan(study_id, sha, files, folder)


def check_disk_space(plan: DownloadPlan, *, margin: int = DISK_MARGIN_BYTES) -> tuple[int, int]:
    """(bytes needed, bytes free); :class:`StudyError` when they do not fit."""
    need = plan.missing_bytes()
    probe = plan.folder
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    if need and need + margin > free:
        raise StudyError(
            f"the study needs {human_bytes(need)} more disk space, but only {human_bytes(free)} "
            f"is free on the disk of {plan.folder}; free some space (or choose another folder "
            "with --data-dir DIR) and start again")
    return need, free


def human_bytes(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if abs(n) < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} GB"


def _fetch(client: ServerClient, participant: str, f: RemoteFile, dest: Path,
           done_before: int, total: int, progress: Progress | None) -> None:
    part = _part(dest)
    have = part.stat().st_size if part.is_file() else 0
    if have > f.size:
        part.unlink()
        have = 0
    headers = {"Range": f"bytes={have}-"} if 0 < have < f.size else {}
    url = participant_path(participant, "files/" + quote(f.path))
    if have < f.size:
        with client.open("GET", url, headers=headers) as resp:
            if resp.status == 206:
                mode = "ab"
            else:  # the server sent the whole file: start over
                mode, have = "wb", 0
            read = getattr(resp, "read1", resp.read)  # read1: whatever has arrived
            with open(part, mode) as out:
                while True:
                    try:
                        chunk = read(NET_CHUNK)
                    except OSError as exc:
                        raise ServerUnavailable(f"the download of {f.path} was cut off "
                                                f"({plain_reason(exc)})") from None
                    if not chunk:
                        break
                    if have + len(chunk) > f.size:
                        raise StudyError(f"the study server sent more of {f.path} than its "
                                         "listed size")
                    out.write(chunk)
                    have += len(chunk)
                    if progress is not None:
                        progress(done_before + have, total, f.path)
    if have != f.size:
        raise ServerUnavailable(f"the download of {f.path} stopped at {have} of {f.size} "
                                "bytes")
    actual = _sha256(part)
    if actual != f.sha256:
        part.unlink()
        raise StudyError(f"{f.path} arrived with sha256 {actual[:12]}..., not the study's "
                         f"{f.sha256[:12]}...: refused (the download was corrupted or the "
                         "server's copy changed); start again, or tell the experimenter")
    part.replace(dest)


RETRIES = 6
"""Attempts per file when the server asks to wait (429) or the connection drops; each
retry resumes with a Range request."""


def download_study(client: ServerClient, participant: str, plan: DownloadPlan, *,
                   progress: Progress | None = None,
                   sleep: Callable[[float], None] = time.sleep,
                   notice: Callable[[str], None] = log.info) -> Path:
    """Fetch every missing file of ``plan``; returns the local study folder. A file cut off
    or rate-limited is retried (resuming) a few times with backoff, each retry told to
    ``notice`` in the participant's words; then :class:`ServerUnavailable` (call again to
    resume). :class:`StudyError` when a file does not match its checksum."""
    plan.folder.mkdir(parents=True, exist_ok=True)
    missing = plan.missing()
    total = plan.missing_bytes()
    done = 0
    for f in missing:
        dest = plan.local(f)
        dest.parent.mkdir(parents=True, exist_ok=True)
        part = _part(dest)
        before = max(f.size - (part.stat().st_size if part.is_file() else 0), 0)
        for attempt in range(1, RETRIES + 1):
            try:
                _fetch(client, participant, f, dest, done - (f.size - before), total,
                       progress)
                plan.verified(f)
                break
            except ServerUnavailable as exc:
                if attempt == RETRIES:
                    kept = sum(1 for g in plan.files if plan.local(g).is_file())
                    raise ServerUnavailable(
                        f"{exc}; {kept} of the {len(plan.files)} files are downloaded and "
                        "kept: start again later to download the rest", exc.retry_after
                    ) from None
                wait = min(exc.retry_after if exc.retry_after is not None
                           else 2.0 ** attempt, 60.0)
                notice(f"The download paused ({exc}); trying again in {wait:.0f} s "
                       f"(try {attempt + 1} of {RETRIES}).")
                sleep(wait)
        done += before
    manifest = plan.folder / "manifest.json"
    if _sha256(manifest) != plan.manifest_sha256:
        manifest.unlink()
        raise StudyError("the downloaded manifest does not match the study version the server "
                         "named; start again")
    if progress is not None:
        progress(total, total, "")
    return plan.folder
