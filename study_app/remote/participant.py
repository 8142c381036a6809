"""``cgvq-study run --server``: the participant's side of a served study, before and after the
player runs.

:func:`fetch_study` asks the server for the participant's study version, shows its size and
the free disk space, and downloads what is missing (a progress bar on the terminal the app
was started from) into the participant's data folder, where the session file lives too. When
the server cannot be reached but the study was downloaded before, the participant carries on
offline: the uploads catch up once the server is back. :func:`start_uploader` follows the
session file from a background thread; :func:`upload_report` is the end screen's sentence.
"""

from __future__ import annotations

import json
import logging
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from session_store.errors import StudyError
from session_store.invite import Invite

from .download import check_disk_space, download_study, human_bytes, study_plan
from .http import ServerClient, ServerRefused, ServerUnavailable
from .stall_note import StallNote
from .uploader import WITHDRAWN, Uploader, participant_reason

log = logging.getLogger(__name__)

APP_DIR = "cgvq-study"
FLUSH_AT_END_S = 20.0
"""How long the end screen waits for the last uploads before it reports."""


def default_data_dir() -> Path:
    """Where downloaded studies and session files live: the platform's per-user data folder
    (not a cache: the session file is the participant's result)."""
    if sys.platform.startswith("win"):
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Application Support"
    else:
        base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return base / APP_DIR


@dataclass(frozen=True)
class RemoteStudy:
    folder: Path
    """The downloaded study folder (one per study version)."""
    sessions_dir: Path
    """Where the participant's session file lives (shared by the study's versions)."""
    offline: bool = False
    verified_sha256: Mapping[Path, str] = field(default_factory=dict)
    """Files the download hashed in this run (see :meth:`DownloadPlan.verified_sha256`)."""


def _last_path(data_dir: Path, invite: Invite) -> Path:
    return data_dir / f"last-{invite.participant}.json"


def fetch_study(invite: Invite, data_dir: str | Path | None = None, *,
                say: Callable[[str], None] = print, progress: bool = True) -> RemoteStudy:
    """Download (or find in the data folder) the participant's study; see the module doc."""
    data_dir = Path(data_dir) if data_dir is not None else default_data_dir()
    client = ServerClient(invite.server, invite.token)
    last = _last_path(data_dir, invite)
    say(f"Connecting to the study server {invite.server} ...")
    try:
        plan = study_plan(client, invite.participant, data_dir)
    except ServerUnavailable as exc:
        found = _last_study(last, invite.server)
        if found is not None:
            why = participant_reason(str(exc))
            say(f"{why[:1].upper()}{why[1:]}. The study downloaded before is used; your "
                "answers are kept on this computer and sent when the server answers again "
                "(while the study runs, or the next time you start it).")
            return found
        raise ServerUnavailable(f"{exc}: the server may be down or this computer offline; "
                                "try again later (anything downloaded so far is kept); if "
                                "it keeps failing, tell the experimenter",
                                exc.retry_after) from None
    except ServerRefused as exc:
        if exc.status not in (401, 403):
            raise
        raise ServerRefused(f"{exc}: start the study with the invitation (or the command) the "
                            "experimenter sent you, unchanged; if you did, tell the "
                            "experimenter", exc.status, exc.detail) from None
    if plan.folder.is_dir():
        say(f"Study {plan.study_id}: checking the files already on this computer...")
    need, free = check_disk_space(plan)
    total = plan.total_bytes
    if need:
        say(f"Study {plan.study_id}: {human_bytes(total)} in {len(plan.files)} files, "
            f"{human_bytes(need)} to download; {human_bytes(free)} free on this disk.")
        from tqdm.auto import tqdm

        with tqdm(total=need, unit="B", unit_scale=True, desc="download",
                  disable=not progress) as bar, StallNote(bar) as stall:
            def step(done: int, _total: int, _name: str) -> None:
                stall.moved()
                bar.update(done - bar.n)

            def told(text: str) -> None:  # on its own line, not glued to the bar
                if progress:
                    bar.write(text, file=sys.stderr)
                else:
                    say(text)

            download_study(client, invite.participant, plan, progress=step, notice=told)
    else:
        say(f"Study {plan.study_id}: all {len(plan.files)} files ({human_bytes(total)}) are "
            "already on this computer.")
    sessions = plan.folder.parent / "sessions"
    last.parent.mkdir(parents=True, exist_ok=True)
    part = last.with_name(last.name + ".part")  # replaced whole: a crash leaves the old one
    part.write_text(json.dumps({"server": invite.server, "folder": str(plan.folder),
                                "sessions_dir": str(sessions)}) + "\n", encoding="utf-8")
    os.replace(part, last)
    return RemoteStudy(plan.folder, sessions, verified_sha256=plan.verified_sha256())


def _last_study(last: Path, server: str) -> RemoteStudy | None:
    """The study downloaded before from ``server`` (to run while it cannot be reached), or
    None. The note is only a hint: an unreadable one counts as none."""
    try:
        info = json.loads(last.read_text(encoding="utf-8"))
        folder, sessions = Path(info["folder"]), Path(info["sessions_dir"])
        same = info.get("server") == server
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if same and (folder / "manifest.json").is_file():
        return RemoteStudy(folder, sessions, offline=True)
    return None


def start_uploader(invite: Invite, session_path: Path) -> Uploader:
    """The background upload of the participant's session file (it waits for the file)."""
    return Uploader(session_path, ServerClient(invite.server, invite.token),
                    invite.participant).start()


def upload_report(uploader: Uploader, timeout: float = FLUSH_AT_END_S) -> tuple[bool, str]:
    """(everything arrived, the sentence for the end screen), after waiting for the last
    uploads at most ``timeout`` seconds."""
    status = uploader.flush(timeout)
    return status.all_arrived, status.describe()


def check_invite_args(server: str | None, participant: str | None, token: str | None,
                      invite_file: str | Path | None) -> Invite:
    """The invite from ``--invite FILE`` or ``--server/--participant/--token``."""
    from session_store.invite import read_invite

    if invite_file is not None:
        if server or token:
            raise StudyError("give either --invite FILE or --server and --token, not both")
        inv = read_invite(invite_file)
        if participant and participant != inv.participant:
            raise StudyError(f"--participant {participant} differs from the invite's "
                             f"{inv.participant}")
        return inv
    if not (server and participant and token):
        raise StudyError("with --server also give --participant and --token (or use the "
                         "invite file: --invite FILE)")
    return Invite(server, participant, token)


BLOCK_FLUSH_S = 15.0
"""How long the app waits for its uploads before it asks for the next block."""


def request_block(client: ServerClient, participant: str, uploader: Uploader,
                  session_id: str, block: int, last: str | None) -> dict:
    """The next block of an adaptive session from the study server, once the uploads so far
    arrived (the server plans from them); ``ServerUnavailable``/``ServerRefused`` otherwise."""
    from session_store.protocol import PROTOCOL

    status = uploader.flush(BLOCK_FLUSH_S)
    if status.withdrawn:
        raise ServerRefused(WITHDRAWN, 410, WITHDRAWN)
    if not status.all_arrived:
        raise ServerUnavailable(f"the answers so far have not all reached the study server "
                                f"({status.describe()})")
    return client.json("POST", f"/api/v1/participants/{participant}/block",
                       {"protocol": PROTOCOL, "session_id": session_id, "block": block,
                        "last": last})
