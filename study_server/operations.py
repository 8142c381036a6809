"""The experimenter's operations on a served study that need no running server: invite
participants, back the database up (also while serving), withdraw a participant."""

from __future__ import annotations

import csv
import os
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from session_store.errors import StudyError
from session_store.ids import check_participant_id
from session_store.invite import Invite, check_server_url, read_invites
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


def invite(study: str | Path, n: int, out_csv: str | Path, *, prefix: str = "P",
           server: str = "http://127.0.0.1:8000", files_dir: str | Path | None = None
           ) -> list[Invite]:
    """Create ``n`` participants with random tokens (only their sha256 is stored) and write
    ``participant,token,server,command`` rows to ``out_csv`` (mode 0600)."""
    if n < 1:
        raise StudyError(f"--n {n}: invite at least one participant")
    check_participant_id(f"{prefix}1")
    server = check_server_url(server)
    folder = load_study(study).folder
    out = Path(out_csv)
    if out.exists():
        raise StudyError(f"{out} exists already (it holds earlier tokens); choose another --out")
    with ServerStore(state_path(folder)) as store:
        ids = _next_ids(store.participant_ids(), prefix, n)
        invites = [Invite(server, pid, new_token()) for pid in ids]
        out.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            with os.fdopen(fd, "w", newline="", encoding="utf-8") as fh:
                writer = csv.writer(fh)
                writer.writerow(INVITE_COLUMNS)
                for inv in invites:
                    writer.writerow([inv.participant, inv.token, inv.server, inv.command()])
            store.add_participants([(i.participant, token_sha256(i.token)) for i in invites],
                                   utc_now())
        except BaseException:
            out.unlink(missing_ok=True)
            raise
    if files_dir is not None:
        for inv in invites:
            inv.write(files_dir)
    return invites


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
    tombstone: Tombstone
    deleted_files: list[Path]
    wal_cleared: bool


def withdraw(study: str | Path, participant: str, reason: str = "withdrawn on request"
             ) -> Withdrawal:
    """Delete a participant's rows (entries, session, flags, token) and their session file
    in the study folder; keep a tombstone without personal data."""
    check_participant_id(participant)
    folder = Path(study)
    src = state_path(folder)
    if not src.is_file():
        raise StudyError(f"{folder} has no server database ({src})")
    with ServerStore(src, create=False) as store:
        stone = store.withdraw(participant, utc_now(), reason)
        cleared = store.checkpoint()
    deleted = []
    for suffix in ("", "-wal", "-shm"):
        p = folder / SESSIONS_DIR / f"{participant}.sqlite{suffix}"
        if p.exists():
            p.unlink()
            deleted.append(p)
    return Withdrawal(stone, deleted, cleared)
