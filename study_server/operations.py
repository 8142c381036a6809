"""The experimenter's operations on a served study that need no running server: invite
participants, back the database up (also while serving), withdraw a participant."""

from __future__ import annotations

import contextlib
import csv
import os
import re
import shutil
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from session_store.errors import StudyError
from session_store.ids import check_participant_id
from session_store.invite import INVITE_SUFFIX, Invite, check_server_url, read_invites
from session_store.records import utc_now
from session_store.study_folder import SESSIONS_DIR, load_study

from .auth import new_token, token_sha256
from .storage import STATE_DIR, ServerStore, Tombstone, state_path

INVITE_COLUMNS = ("participant", "token", "server", "command")
__all__ = ["backup", "invite", "read_invites", "withdraw"]


def _next_ids(existing: list[str], prefix: str, n: int) -> list[str]:
    pattern = re.compile(rf"^{re.escape(prefix)}(\d+)$")
    used = [int(m.group(1)) for e in existing if (m := pattern.match(e))]
    start = max(used, default=0) + 1
    width = max(2, len(str(start + n - 1)))
    return [f"{prefix}{k:0{width}d}" for k in range(start, start + n)]


MAX_INVITES = 10_000
"""Most participants one ``invite`` call creates (run it again for more)."""


def invite(study: str | Path, n: int, out_csv: str | Path, *, prefix: str = "P",
           server: str = "http://127.0.0.1:8000", files_dir: str | Path | None = None
           ) -> list[Invite]:
    """Create ``n`` participants with random tokens (only their sha256 is stored) and write
    ``participant,token,server,command`` rows to ``out_csv`` (mode 0600), and with
    ``files_dir`` one invite file per participant. Every input is checked before anything is
    written; a failure removes what this call wrote and registers nobody."""
    if n < 1:
        raise StudyError(f"--n {n}: invite at least one participant")
    if n > MAX_INVITES:
        raise StudyError(f"--n {n}: invite from 1 to {MAX_INVITES} participants at a time "
                         "(run invite again for more)")
    check_participant_id(f"{prefix}1")
    server = check_server_url(server)
    folder = load_study(study).folder
    out = Path(out_csv)
    if out.is_dir():
        raise StudyError(f"--out {out} is a folder; give the path of a new CSV file, e.g. "
                         f"{out / 'invites.csv'}")
    if out.exists():
        raise StudyError(f"--out {out} exists already (it may hold earlier tokens); choose "
                         "another --out")
    _check_can_create(out.parent, "--out")
    files = Path(files_dir) if files_dir is not None else None
    if files is not None:
        if files.exists() and not files.is_dir():
            raise StudyError(f"--files {files} is a file; give a folder for the invite files")
        _check_can_create(files, "--files")
    state_dir = folder / STATE_DIR
    fresh = not state_dir.exists()
    written: list[Path] = []
    made: list[Path] = []
    try:
        with ServerStore(state_path(folder)) as store:
            ids = _next_ids(store.participant_ids(), prefix, n)
            invites = [Invite(server, pid, new_token()) for pid in ids]
            if files is not None:
                clash = [files / f"{i.participant}{INVITE_SUFFIX}" for i in invites]
                clash = [p for p in clash if p.exists()]
                if clash:
                    raise StudyError(f"--files {files} holds invite files already (e.g. "
                                     f"{clash[0].name}); choose another --files folder")
            made += _make_folder(out.parent)
            fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            written.append(out)
            with os.fdopen(fd, "w", newline="", encoding="utf-8") as fh:
                writer = csv.writer(fh)
                writer.writerow(INVITE_COLUMNS)
                for inv in invites:
                    writer.writerow([inv.participant, inv.token, inv.server, inv.command()])
            if files is not None:
                made += _make_folder(files)
                for inv in invites:
                    written.append(files / f"{inv.participant}{INVITE_SUFFIX}")
                    inv.write(files)
            store.add_participants([(i.participant, token_sha256(i.token)) for i in invites],
                                   utc_now())
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        for path in reversed(made):
            with contextlib.suppress(OSError):
                path.rmdir()
        if fresh:
            shutil.rmtree(state_dir, ignore_errors=True)
        raise
    return invites


def _check_can_create(folder: Path, flag: str) -> None:
    """Refuse a folder path whose nearest existing part is a file (before writing)."""
    for part in (folder, *folder.parents):
        if part.exists():
            if not part.is_dir():
                raise StudyError(f"{flag}: {part} is a file, not a folder")
            return


def _make_folder(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; the ones created, outermost first."""
    missing = [p for p in (folder, *folder.parents) if not p.exists()]
    folder.mkdir(parents=True, exist_ok=True)
    return list(reversed(missing))


def backup(study: str | Path, out: str | Path | None = None) -> Path:
    """An online backup of the server database (consistent while the server writes)."""
    folder = Path(study)
    src = state_path(folder)
    if not src.is_file():
        raise StudyError(f"{folder} has no server database ({src}); nothing to back up")
    if out is None:
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
        out = folder / STATE_DIR / "backups" / f"state-{stamp}.sqlite"
    with ServerStore(src, create=False) as store:
        return store.backup(out)


@dataclass
class Withdrawal:
    tombstone: Tombstone | None
    """None when the participant had withdrawn before (only backups were purged)."""
    deleted_files: list[Path]
    wal_cleared: bool
    backups_holding: list[Path] = field(default_factory=list)
    """Backups in ``server/backups/`` that still hold the participant's data."""
    backups_purged: list[Path] = field(default_factory=list)
    """Backups the participant's data were deleted from (``purge_backups``)."""


def _purge_backups(folder: Path, participant: str, at: str, reason: str, purge: bool
                   ) -> tuple[list[Path], list[Path]]:
    """The backups that hold ``participant`` and, with ``purge``, those their data were
    deleted from, as in the live database (a tombstone kept; other participants untouched)."""
    holding, purged = [], []
    for path in sorted((folder / STATE_DIR / "backups").glob("*.sqlite")):
        with ServerStore(path, create=False) as store:
            if store.participant(participant) is None:
                continue
            if not purge:
                holding.append(path)
                continue
            store.withdraw(participant, at, reason)
            store.checkpoint()
        purged.append(path)
    return holding, purged


def withdraw(study: str | Path, participant: str, reason: str = "withdrawn on request",
             *, purge_backups: bool = False) -> Withdrawal:
    """Delete a participant's rows (entries, session, flags, token) and their session file
    in the study folder; keep a tombstone without personal data. Names the backups that
    still hold them, or with ``purge_backups`` deletes them there too (also for a
    participant who withdrew before)."""
    check_participant_id(participant)
    folder = Path(study)
    src = state_path(folder)
    if not src.is_file():
        raise StudyError(f"{folder} has no server database ({src})")
    with ServerStore(src, create=False) as store:
        earlier = next((t for t in store.tombstones() if t.participant == participant), None)
        if earlier is not None and purge_backups:
            stone, cleared = None, True
        else:
            stone = store.withdraw(participant, utc_now(), reason)
            cleared = store.checkpoint()
    at = stone.withdrawn_at if stone is not None else earlier.withdrawn_at
    holding, purged = _purge_backups(folder, participant, at, reason, purge_backups)
    deleted = []
    for suffix in ("", "-wal", "-shm"):
        p = folder / SESSIONS_DIR / f"{participant}.sqlite{suffix}"
        if p.exists():
            p.unlink()
            deleted.append(p)
    return Withdrawal(stone, deleted, cleared, holding, purged)
