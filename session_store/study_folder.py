"""A study folder: ``manifest.json``, optional ``briefing.md`` / ``consent.md``, the videos,
and the ``sessions/`` folder beside them.

The player, the study server and the experimenter's tools all read a study through
:func:`load_study`, so the names of its files are defined here, once.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

from stimuli_manifests import LoadedManifest, Manifest, StimuliError, load_manifest

from .errors import StudyError
from .ids import check_participant_id

MANIFEST_NAME = "manifest.json"
BRIEFING_NAME = "briefing.md"
CONSENT_NAME = "consent.md"
SESSIONS_DIR = "sessions"
SERVER_STATE_DIR = "server"
"""Where ``cgvq-study serve`` keeps a served study's state (sessions, invites, versions)."""
SERVER_STATE_FILE = "state.sqlite"


@dataclass
class Study:
    """A loaded study folder."""

    folder: Path
    loaded: LoadedManifest
    briefing: str | None
    consent: str | None
    text_hashes: dict[str, str] = field(default_factory=dict)
    """sha256 of the bytes of each text file read (``briefing.md``, ``consent.md``)."""

    @property
    def manifest(self) -> Manifest:
        return self.loaded.manifest

    def session_path(self, participant: str, sessions_dir: Path | None = None) -> Path:
        """Where this participant's session file lives (``<study>/sessions/<id>.sqlite``)."""
        participant = check_participant_id(participant)
        folder = sessions_dir or self.folder / SESSIONS_DIR
        if folder.exists() and not folder.is_dir():
            raise StudyError(f"the sessions folder {folder} is a file, not a folder; choose a "
                             "folder for the session files")
        return folder / f"{participant}.sqlite"

    def text_sha256(self, name: str) -> str | None:
        """sha256 of a study text file as read (``briefing.md``/``consent.md``), or None."""
        return self.text_hashes.get(name)


def load_study(folder: str | Path) -> Study:
    """Load a study folder (or a manifest file inside one)."""
    folder = Path(folder)
    if folder.is_file():
        manifest_path, folder = folder, folder.parent
    else:
        manifest_path = folder / MANIFEST_NAME
    if not folder.is_dir():
        raise StudyError(f"study folder not found: {folder}")
    if not manifest_path.is_file():
        raise StudyError(
            f"{folder} holds no {MANIFEST_NAME}; a study folder needs one (see README, "
            "'Preparing a study folder')"
        )
    try:
        loaded = load_manifest(manifest_path)
    except StimuliError as exc:
        raise StudyError(str(exc)) from None

    hashes: dict[str, str] = {}

    def text(name: str) -> str | None:
        p = folder / name
        if not p.is_file():
            return None
        data = p.read_bytes()
        hashes[name] = hashlib.sha256(data).hexdigest()
        try:
            return data.decode("utf-8-sig").replace("\r\n", "\n")
        except UnicodeDecodeError:
            raise StudyError(f"{p} is not UTF-8 text; save it as UTF-8") from None

    return Study(folder, loaded, text(BRIEFING_NAME), text(CONSENT_NAME), hashes)
