"""The experimenter's side: ``pull`` every session from the server, as received.

Each participant's entries are fetched page by page and replayed into a new session file
with :class:`~session_store.Replica` (which checks the chain again), so the files are
regular session files for ``verify`` and ``cgvq-analyze``. The server's flags travel along:
they are printed and kept in ``server_listing.json`` beside the files.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

from session_store import (
    OutboxEntry,
    Replica,
    SessionRecord,
    VerifyReport,
    read_session,
    verify_session,
)
from session_store.answers import (
    answer_rows,
    latest_answers,
    screening_rows,
    write_answers_csv,
    write_screenings_csv,
)
from session_store.errors import StudyError
from session_store.ids import check_participant_id
from session_store.protocol import (
    ADMIN_SESSIONS,
    PULL_LISTING_FILE,
    admin_entries_path,
    admin_manifest_path,
)
from session_store.ratings_csv import write_ratings_csv
from stimuli_manifests.errors import TableError
from stimuli_manifests.tables import ANSWERS, RATINGS, SCREENINGS, read_table

from .http import ServerClient, ServerRefused

log = logging.getLogger(__name__)

PAGE = 1000
LISTING_FILE = PULL_LISTING_FILE
TABLES_NOTE = "pulled_tables.json"
"""Beside the sessions: the tables (``--csv``, ``--answers``) pulls into this folder wrote,
so that a later pull can take withdrawn participants out of them."""


@dataclass
class PulledSession:
    participant: str
    path: Path | None
    report: VerifyReport | None
    version: int | None
    manifest_sha256: str | None
    flags: list[dict[str, Any]] = field(default_factory=list)
    n_answers: int = 0  # questions answered (the answers themselves stay in the file)
    vision: dict[str, str] = field(default_factory=dict)  # vision check -> outcome


@dataclass
class PullResult:
    study_id: str
    sessions: list[PulledSession]
    not_started: list[str]
    withdrawn: list[str]
    listing_path: Path
    csv_path: Path | None = None
    n_csv_rows: int = 0
    answers_path: Path | None = None
    n_answer_rows: int = 0
    screenings_path: Path | None = None
    removed: list[Path] = field(default_factory=list)
    """Copies an earlier pull left of participants who have withdrawn since (deleted)."""
    manifests: dict[str, Path] = field(default_factory=dict)
    """sha256 -> ``manifest.<sha12>.json``: the manifest of each version the sessions ran."""
    withdrew_in_app: list[str] = field(default_factory=list)
    """Participants whose session says they withdrew in the app: in no table."""
    rewritten: list[Path] = field(default_factory=list)
    """Tables an earlier pull wrote that held rows of participants who have withdrawn since,
    written again from this pull's sessions."""


def server_refits(server: str, admin_token: str) -> int | None:
    """How many times the server has refit its adaptive allocation's model for the current
    study version (None: a full design, nothing is refit)."""
    listing = ServerClient(server, admin_token, timeout=30).json("GET", ADMIN_SESSIONS)
    refits = listing.get("refits")
    return None if refits is None else int(refits)


def _remove_withdrawn(out: Path, withdrawn: list[str]) -> list[Path]:
    """Delete the session files an earlier pull into ``out`` wrote for participants who have
    withdrawn since: their data is deleted on the server, and an analysis of ``out`` would
    otherwise still use it."""
    removed = []
    for pid in withdrawn:
        path = out / f"{pid}.sqlite"
        if path.is_file():
            path.unlink()
            removed.append(path)
        for side in ("-wal", "-shm"):  # SQLite's side files hold the same data
            Path(f"{path}{side}").unlink(missing_ok=True)
    return removed


def _entries(client: ServerClient, pid: str) -> list[OutboxEntry]:
    out: list[OutboxEntry] = []
    after = 0
    while True:
        page = client.json("GET", admin_entries_path(pid) + "?" +
                           urlencode({"after": after, "limit": PAGE}))
        rows = page["entries"]
        for r in rows:
            out.append(OutboxEntry(int(r["seq"]), str(r["kind"]), json.loads(r["body_json"]),
                                   str(r["prev_hash"]), str(r["entry_hash"])))
        if len(rows) < PAGE:
            return out
        after = out[-1].seq


def _build(path: Path, entries: list[OutboxEntry]) -> None:
    """Replay ``entries`` into a new session file at ``path`` (replacing an older pull)."""
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        built = Path(tmp) / path.name
        with Replica.create(built, entries[0]) as rep:
            rep.accept(entries[1:])
        for suffix in ("-wal", "-shm"):
            Path(f"{path}{suffix}").unlink(missing_ok=True)
        shutil.move(str(built), str(path))
    path.chmod(0o600)


_MANIFEST_NAME = re.compile(r"manifest\.[0-9a-f]{12}\.json")


def manifest_name(manifest_sha256: str) -> str:
    """The file a pull saves a version's manifest as (beside the sessions)."""
    return f"manifest.{manifest_sha256[:12]}.json"  # what _MANIFEST_NAME matches


def screenings_name(answers: Path) -> Path:
    """Where the vision checks go beside the answers table (personal data too)."""
    return answers.with_name(f"{answers.stem}_screenings.csv")


def _save_manifests(client: ServerClient, out: Path,
                    sessions: list[PulledSession]) -> dict[str, Path]:
    """Each version's manifest as the server registered it: sessions of an earlier version
    are refused under the edited manifest, and this is the one to analyse them with. The
    copy is checked against its sha256 (a manifest that differs would refuse them all)."""
    saved = {}
    for sha in sorted({s.manifest_sha256 for s in sessions if s.manifest_sha256}):
        answer = client.json("GET", admin_manifest_path(sha))
        raw = str(answer.get("text", "")).encode("utf-8") if isinstance(answer, dict) else b""
        if hashlib.sha256(raw).hexdigest() != sha:
            raise StudyError(f"the server's manifest of version {sha[:12]}... does not match "
                             "its sha256; pull again")
        path = out / manifest_name(sha)
        path.write_bytes(raw)
        saved[sha] = path
    return saved


def _check_outputs(out: Path, csv: str | Path | None, answers: str | Path | None) -> None:
    """Before anything is fetched: the two tables are two files, neither a folder, and
    neither one of the files pull writes into ``out`` (a session file, the listing, a
    manifest), which it would replace without a word."""
    named = {"--csv": csv, "--answers": answers}
    given = {opt: Path(p).resolve() for opt, p in named.items() if p is not None}
    if len(given) == 2 and given["--csv"] in (given["--answers"],
                                              screenings_name(given["--answers"])):
        raise StudyError(f"--csv {csv} is a file --answers writes ({given['--csv'].name}); "
                         "give two files")
    for opt, path in given.items():
        if path.is_dir():
            raise StudyError(f"{opt} {named[opt]} is a folder; give a file name")
        inside = path.parent == out.resolve()
        if inside and (path.suffix == ".sqlite" or path.name in (LISTING_FILE, TABLES_NOTE)
                       or _MANIFEST_NAME.fullmatch(path.name)):
            raise StudyError(f"{opt} {named[opt]} is a file pull writes into {out}; name "
                             "the table otherwise")


def pull(server: str, admin_token: str, out: str | Path, *, csv: str | Path | None = None,
         answers: str | Path | None = None,
         progress: Callable[[str], None] | None = None) -> PullResult:
    """Fetch every session into ``out/<participant>.sqlite`` (see the module doc); ``csv``
    writes the ratings table, ``answers`` the questionnaire answers (and the vision checks
    beside it as ``<name>_screenings.csv``), which are personal data and never go into the
    ratings table."""
    out = Path(out)
    _check_outputs(out, csv, answers)
    client = ServerClient(server, admin_token, timeout=120)
    listing = client.json("GET", ADMIN_SESSIONS)
    if out.exists() and not out.is_dir():
        raise StudyError(f"--out {out} is a file; give a folder")
    if not out.exists():
        out.mkdir(mode=0o700, parents=True)
        out.chmod(0o700)  # the pulled data is personal: owner only
    sessions: list[PulledSession] = []
    not_started: list[str] = []
    records: dict[str, SessionRecord] = {}
    gone: list[str] = []  # listed, then no session: withdrawn while this pull ran
    for p in listing["participants"]:
        pid = check_participant_id(p["participant"])
        s = p.get("session")
        if s is None:
            not_started.append(pid)
            continue
        if progress is not None:
            progress(pid)
        try:
            entries = _entries(client, pid)
        except ServerRefused as exc:
            if exc.status != 404:
                raise
            gone.append(pid)
            continue
        if not entries:
            not_started.append(pid)
            continue
        path = out / f"{pid}.sqlite"
        _build(path, entries)
        report = verify_session(path)
        record = read_session(path)
        sessions.append(PulledSession(
            pid, path, report, s.get("version"), s.get("manifest_sha256"),
            list(p.get("flags", [])), len(latest_answers(record.answers)),
            {x["test"]: x["outcome"] for x in record.screenings}))
        records[pid] = record
    # a withdrawal during the pull: the listing taken at the end is the one that counts
    listing = client.json("GET", ADMIN_SESSIONS)
    withdrawn = [check_participant_id(w["participant"]) for w in listing.get("withdrawn", [])]
    unexplained = sorted(set(gone) - set(withdrawn))
    if unexplained:
        raise StudyError(f"the server lost the session of {', '.join(unexplained)} during "
                         "this pull without a withdrawal; pull again")
    sessions = [x for x in sessions if x.participant not in withdrawn]
    # A participant who withdrew in the app keeps their session file here (it carries the
    # withdrawal, which the analysis honours), but no table would: their rows stay out.
    kept = [records[x.participant] for x in sessions
            if not records[x.participant].info.withdrawn]
    listing_path = out / LISTING_FILE
    listing_path.write_text(json.dumps(listing, indent=2) + "\n", encoding="utf-8")
    listing_path.chmod(0o600)
    result = PullResult(str(listing["study_id"]), sessions, not_started, withdrawn,
                        listing_path, removed=_remove_withdrawn(out, withdrawn),
                        manifests=_save_manifests(client, out, sessions),
                        withdrew_in_app=[x.participant for x in sessions
                                         if records[x.participant].info.withdrawn])
    if csv is not None:
        result.csv_path, result.n_csv_rows = Path(csv), _write_ratings(kept, Path(csv))
    if answers is not None:
        result.answers_path = Path(answers)
        result.n_answer_rows, result.screenings_path = _write_answers(kept, Path(answers))
    result.rewritten = _rewrite_earlier_tables(out, kept, withdrawn + result.withdrew_in_app,
                                               csv=csv, answers=answers)
    return result


def _write_ratings(kept: list[SessionRecord], path: Path) -> int:
    rows = [row for r in kept for row in r.ratings]
    write_ratings_csv(rows, path)
    path.chmod(0o600)
    return len(rows)


def _write_answers(kept: list[SessionRecord], path: Path) -> tuple[int, Path | None]:
    """The answers table and, where any check was taken, the vision checks beside it."""
    table = [row for r in kept for row in answer_rows(r)]
    write_answers_csv(table, path)
    path.chmod(0o600)
    screenings = None
    if screening_table := [row for r in kept for row in screening_rows(r)]:
        screenings = write_screenings_csv(screening_table, screenings_name(path))
        screenings.chmod(0o600)
    return len(table), screenings


def _rewrite_earlier_tables(out: Path, kept: list[SessionRecord], withdrawn: list[str], *,
                            csv: str | Path | None, answers: str | Path | None) -> list[Path]:
    """Write again the tables earlier pulls into ``out`` wrote (this pull's aside), where
    they still hold rows of a participant who has withdrawn, on the server (their data is
    deleted there) or in the app (no table holds them): a table left as it was would keep
    them. Note this pull's tables."""
    note = out / TABLES_NOTE
    now = {k: Path(v).resolve() for k, v in (("csv", csv), ("answers", answers))
           if v is not None}
    tables = _noted_tables(note)
    rewritten: list[Path] = []
    gone = set(withdrawn)
    for kind, paths in tables.items():
        for path in paths:
            if not gone or path in now.values():
                continue
            files = [path] if kind == "csv" else [path, screenings_name(path)]
            if not any(_holds_participant(f, kind, gone) for f in files):
                continue
            if kind == "csv":
                _write_ratings(kept, path)
            elif _write_answers(kept, path)[1] is None:  # nobody left took a check
                screenings_name(path).unlink(missing_ok=True)
            rewritten.append(path)
    for kind, path in now.items():
        tables.setdefault(kind, [])
        if path not in tables[kind]:
            tables[kind].append(path)
    if any(tables.values()):
        note.write_text(json.dumps({k: [str(p) for p in v] for k, v in tables.items()},
                                   indent=2) + "\n", encoding="utf-8")
        note.chmod(0o600)
    return rewritten


def _noted_tables(note: Path) -> dict[str, list[Path]]:
    """The tables earlier pulls noted (kind -> paths); none when the note is unreadable."""
    try:
        data = json.loads(note.read_text(encoding="utf-8"))
        return {k: [Path(p) for p in data[k] if isinstance(p, str)]
                for k in ("csv", "answers") if isinstance(data.get(k), list)}
    except (OSError, ValueError, AttributeError, TypeError):
        return {}


def _holds_participant(path: Path, kind: str, participants: set[str]) -> bool:
    """Whether the table at ``path`` has a row of one of ``participants`` (False when it is
    gone or is no longer a table this toolkit wrote: it is not ours to rewrite)."""
    fmt = (RATINGS if kind == "csv" else
           SCREENINGS if path.name.endswith("_screenings.csv") else ANSWERS)
    try:
        rows = read_table(path, fmt)
    except (OSError, TableError):
        return False
    return any(row.get("participant") in participants for row in rows)
