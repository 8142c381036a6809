"""What the server hands a participant: a version of the study and the files it needs.

The current version is the study folder as it is (``manifest.json``, ``briefing.md`` and
``consent.md`` when present, every stimulus under the manifest's root; of a stimulus
that is a folder, only its numbered ``.png`` frames). Every manifest the
server has served is kept in its database, so a participant whose session is pinned to an
older version is still given that manifest; its videos are served from the folder and checked
by the client against that manifest's sha256 (change a video under a new name, never in
place, while sessions run on the old version).
"""

from __future__ import annotations

import hashlib
import json
import threading
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from session_store.errors import StudyError
from session_store.study_folder import BRIEFING_NAME, CONSENT_NAME, MANIFEST_NAME
from stimuli_manifests import Manifest, StimuliError, parse_manifest
from stimuli_manifests.errors import VideoError
from stimuli_manifests.frame_files import ordered_frames


@dataclass(frozen=True)
class ServedFile:
    path: str
    """Relative to the study folder (POSIX)."""
    local: Path | None
    """On disk; None for a manifest served from the database."""
    size: int
    sha256: str


@dataclass(frozen=True)
class StudyVersion:
    study_id: str
    manifest_sha256: str
    manifest_bytes: bytes
    files: tuple[ServedFile, ...]

    @property
    def total_bytes(self) -> int:
        return sum(f.size for f in self.files)

    def by_path(self) -> dict[str, ServedFile]:
        return {f.path: f for f in self.files}

    def listing(self) -> dict[str, object]:
        return {"study_id": self.study_id, "manifest_sha256": self.manifest_sha256,
                "total_bytes": self.total_bytes,
                "files": [{"path": f.path, "size": f.size, "sha256": f.sha256}
                          for f in self.files]}


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


class FileHashes:
    """sha256 of files on disk, remembered per (size, mtime) so a changed file is re-read."""

    def __init__(self) -> None:
        self._cache: dict[Path, tuple[int, int, str]] = {}
        self._lock = threading.Lock()

    def get(self, path: Path) -> tuple[int, str]:
        st = path.stat()
        with self._lock:
            hit = self._cache.get(path)
        if hit and hit[:2] == (st.st_size, st.st_mtime_ns):
            return st.st_size, hit[2]
        digest = _sha256(path)
        with self._lock:
            self._cache[path] = (st.st_size, st.st_mtime_ns, digest)
        return st.st_size, digest


def _root(manifest: Manifest) -> PurePosixPath:
    root = PurePosixPath(manifest.root.replace("\\", "/"))
    if root.is_absolute() or ".." in root.parts:
        raise StudyError(f"the manifest's root {manifest.root!r} lies outside the study folder; "
                         "a served study keeps its videos inside its folder")
    return root


def build_version(folder: Path, manifest_bytes: bytes, hashes: FileHashes, *,
                  from_disk: bool) -> StudyVersion:
    """The file list of one version (``from_disk``: the folder's current manifest)."""
    try:
        manifest = parse_manifest(json.loads(manifest_bytes), source=MANIFEST_NAME)
    except (ValueError, StimuliError) as exc:
        raise StudyError(f"the study's manifest cannot be served: {exc}") from None
    sha = hashlib.sha256(manifest_bytes).hexdigest()
    files = [ServedFile(MANIFEST_NAME, folder / MANIFEST_NAME if from_disk else None,
                        len(manifest_bytes), sha)]
    for name in (BRIEFING_NAME, CONSENT_NAME):
        p = folder / name
        if p.is_file():
            size, digest = hashes.get(p)
            files.append(ServedFile(name, p, size, digest))
    root = _root(manifest)
    seen: set[str] = set()
    for item in [*manifest.references, *manifest.conditions]:
        rel = root / PurePosixPath(item.path.replace("\\", "/"))
        local = folder.joinpath(*rel.parts)
        if local.is_dir():
            # Only the frames the player reads: notes or a .DS_Store beside them stay private.
            try:
                members = ordered_frames(local)
            except VideoError as exc:
                raise StudyError(f"{item.id}: {exc}") from None
            if not members:
                raise StudyError(f"{item.id}: {local} holds no .png frames; the study cannot "
                                 "be served (run 'cgvq-study check' on it)")
        elif local.is_file():
            members = [local]
        else:
            raise StudyError(f"{item.id}: {local} does not exist; the study cannot be served "
                             "(run 'cgvq-study check' on it)")
        for m in members:
            path = m.relative_to(folder).as_posix()
            if path in seen:
                continue
            seen.add(path)
            if m == local and item.sha256 and not from_disk:
                size, digest = m.stat().st_size, item.sha256
            else:
                size, digest = hashes.get(m)
                if m == local and item.sha256 and digest != item.sha256:
                    raise StudyError(f"{item.id}: {path} does not match the manifest's sha256; "
                                     "run 'cgvq-study check' on the study")
            files.append(ServedFile(path, m, size, digest))
    return StudyVersion(manifest.study_id, sha, manifest_bytes, tuple(files))
