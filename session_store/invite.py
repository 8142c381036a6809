"""The invitation an experimenter sends a participant: server, participant id and token.

It travels as a ready-to-paste command line (``cgvq-study run --server URL --participant ID
--token T``) or as a small JSON file (``cgvq-study run --invite FILE``, which the frozen app
also opens), written by ``cgvq-study invite``.
"""

from __future__ import annotations

import json
import shlex
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from .errors import StudyError
from .ids import check_participant_id

INVITE_FORMAT = "cgvq-invite/1"
INVITE_SUFFIX = ".cgvq-invite.json"


def check_server_url(url: str) -> str:
    """``url`` without a trailing slash, when it is an http(s) URL with a host."""
    parts = urlsplit(url or "")
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise StudyError(f"server address {url!r} is not an http:// or https:// URL "
                         "(e.g. https://study.example.org)")
    if parts.query or parts.fragment:
        raise StudyError(f"server address {url!r} must not carry a query or fragment")
    return url.rstrip("/")


def check_token(token: str) -> str:
    if not isinstance(token, str) or not 16 <= len(token) <= 256 or not token.isascii() \
            or any(c.isspace() for c in token):
        raise StudyError("the token is not valid: copy it exactly as the experimenter sent it "
                         "(16 to 256 characters without spaces)")
    return token


@dataclass(frozen=True)
class Invite:
    """Who a participant is on which server."""

    server: str
    participant: str
    token: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "server", check_server_url(self.server))
        check_participant_id(self.participant)
        check_token(self.token)

    def command(self) -> str:
        """The command line the participant pastes."""
        return ("cgvq-study run --server " + shlex.quote(self.server) + " --participant "
                + shlex.quote(self.participant) + " --token " + shlex.quote(self.token))

    def as_json(self) -> dict[str, str]:
        return {"format": INVITE_FORMAT, "server": self.server,
                "participant": self.participant, "token": self.token}

    def write(self, folder: str | Path) -> Path:
        """Write ``<participant>.cgvq-invite.json`` into ``folder`` (readable by the owner
        only: it holds the token)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{self.participant}{INVITE_SUFFIX}"
        path.touch(mode=0o600)
        path.write_text(json.dumps(self.as_json(), indent=2) + "\n", encoding="utf-8")
        return path


def read_invite(path: str | Path) -> Invite:
    """Read an invite file; a wrong or damaged one is a :class:`StudyError`."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise StudyError(f"invite file not found: {path}") from None
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise StudyError(f"{path} is not an invite file (expected the JSON file the "
                         "experimenter sent)") from None
    if not isinstance(data, dict) or data.get("format") != INVITE_FORMAT:
        raise StudyError(f"{path} is not a {INVITE_FORMAT} invite file")
    try:
        return Invite(str(data["server"]), str(data["participant"]), str(data["token"]))
    except KeyError as exc:
        raise StudyError(f"{path}: the invite lacks {exc.args[0]!r}") from None


def read_invites(path: str | Path) -> list[Invite]:
    """The invites CSV written by ``cgvq-study invite`` (participant,token,server,...)."""
    import csv

    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.DictReader(fh))
    except FileNotFoundError:
        raise StudyError(f"invites file not found: {path}") from None
    except IsADirectoryError:
        raise StudyError(f"{path} is a folder; give the invites CSV file") from None
    except (UnicodeDecodeError, csv.Error):
        raise StudyError(f"{path} is not a UTF-8 invites CSV (columns participant,token,"
                         "server); use the file 'cgvq-study invite' wrote, or save it again "
                         "as CSV UTF-8") from None
    if not rows or not {"participant", "token", "server"} <= set(rows[0]):
        raise StudyError(f"{path} is not an invites CSV (columns participant,token,server)")
    return [Invite(r["server"], r["participant"], r["token"]) for r in rows]
