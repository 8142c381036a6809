"""Checking a returned session file: schema, hash chain, plan consistency, completeness, and
whether the main file holds everything (a ``-wal`` file beside it may hold ratings it lacks).

An exported zip is a copy around the session file: :func:`check_export_copy` checks every
member against ``SHA256SUMS`` and the ratings CSV against the session it was made from. A
fault there damages the copy, never the session: the session file stays the authority.
"""

from __future__ import annotations

import hashlib
import re
import sqlite3
import zipfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from .errors import StudyError
from .ratings_csv import ratings_csv_difference
from .reader import SessionRecord, read_header, read_session, record_from
from .records import SessionInfo, SessionProblem
from .replica import tables_match_outbox
from .schema import DAMAGE_ERRORS, open_existing, wal_pending_bytes
from .sources import CHECKSUM_MEMBER, MAX_MEMBER_BYTES, SESSION_SUFFIX, ZIP_READ_ERRORS

#: the ratings CSV an export writes beside ``<stem>.sqlite`` (older exports: ``ratings.csv``
#: beside ``session.sqlite``)
RATINGS_CSV_SUFFIX = "_ratings.csv"
_SUM_LINE = re.compile(r"^([0-9a-fA-F]{64}) [ *](.+)$")


@dataclass
class VerifyReport:
    """Result of :func:`verify_session`: ``intact`` (schema and hash chain fine) and
    ``complete`` (every planned trial answered and the session finished)."""

    path: Path
    intact: bool
    complete: bool
    n_ratings: int
    n_planned: int
    finished: bool
    problems: list[SessionProblem]
    info: SessionInfo | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def withdrawn(self) -> bool:
        return bool(self.info and self.info.withdrawn)

    @property
    def checked(self) -> bool:
        """False where the path given held nothing to check (missing, or a folder without
        session files): not a damaged file, although it fails the check as one does."""
        return not (self.info is None and self.problems
                    and all(p.nothing_to_check for p in self.problems))

    @property
    def exit_code(self) -> int:
        """0 intact and complete, 1 intact but incomplete (or withdrawn), 2 damaged or
        nothing to check."""
        if not self.intact:
            return 2
        return 0 if self.complete else 1

    @property
    def state(self) -> str:
        """One word for listings: complete, incomplete, withdrawn, damaged or not checked."""
        if not self.checked:
            return "not checked"
        if not self.intact:
            return "damaged"
        if self.complete:
            return "complete"
        return "withdrawn" if self.withdrawn else "incomplete"


def unmerged_wal_warning(path: Path, record: SessionRecord) -> str | None:
    """A warning when the ``-wal`` beside ``path`` holds committed data the main file lacks
    (the main file alone, read as immutable, has fewer ratings or another header)."""
    if wal_pending_bytes(path) == 0:
        return None
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?immutable=1", uri=True)
        con.row_factory = sqlite3.Row
        try:
            alone = read_header(con)
        finally:
            con.close()
    except (sqlite3.DatabaseError, ValueError):
        alone = None
    full = (record.info.finished_at, len(record.ratings))
    if alone is not None and (alone["finished_at"], int(alone["n_ratings"])) == full:
        return None
    missing = len(record.ratings) - (int(alone["n_ratings"]) if alone else 0)
    return (f"{path.name}-wal beside it holds {max(missing, 0)} committed rating(s) or the end "
            f"of the session that {path.name} alone lacks: send the zip made by 'cgvq-study "
            f"export {path.name}' (or keep the -wal file next to it)")


def verify_record(record: SessionRecord, integrity: str = "ok") -> VerifyReport:
    """Completeness and consistency of an already read session."""
    path = record.path
    problems = list(record.problems)
    if integrity != "ok":
        problems.append(SessionProblem(path, None, f"SQLite integrity check: {integrity}"))
    plan = record.plan
    by_idx = {p.index: p for p in plan}
    for p in plan:
        if p.requeue_of is not None:
            orig = by_idx.get(p.requeue_of)
            if orig is None or (orig.stimulus, orig.repetition) != (p.stimulus, p.repetition):
                problems.append(SessionProblem(path, p.index, "re-queued trial does not match "
                                               "the trial it replaces"))
    rows = record.ratings
    seen = {(r["stimulus"], r["repetition"]) for r in rows}
    wanted = {(p.stimulus, p.repetition) for p in plan}
    answered = {r["trial"] for r in rows}
    superseded = {p.requeue_of for p in plan if p.requeue_of is not None}
    unanswered = [p.index for p in plan if p.index not in answered and p.index not in superseded]
    intact = not problems
    finished = record.info.finished_at is not None
    complete = (intact and finished and not record.info.withdrawn and not unanswered
                and seen == wanted)
    report = VerifyReport(path, intact, complete, len(rows), len(wanted), finished, problems,
                          record.info)
    missing = consent_missing(record)
    if missing:
        report.warnings.append(missing)
    return report


def consent_missing(record: SessionRecord) -> str | None:
    """A warning when a session the participant's app wrote holds no consent event (a run
    of an older app killed between creating the file and recording the consent): its
    ratings carry no consent record. Simulated sessions and files of other tools, which ask
    no consent, are left alone."""
    if "timing_mode" not in record.info.settings or record.info.settings.get("simulated"):
        return None
    if any(e.get("kind") == "consent" for e in record.events):
        return None
    return (f"{record.path.name} holds no consent record (the app was stopped between "
            "creating the session and recording the consent): confirm the participant's "
            "consent before using these ratings")


def verify_session(path: str | Path) -> VerifyReport:
    """Check a session file: schema, hash chain, plan consistency, completeness.

    Raises :class:`StudyError` only when the file is not a readable session file at all;
    anything else a damaged file makes the checks raise is reported as damage (state
    ``damaged``, exit code 2), never an exception."""
    path = Path(path)
    con = open_existing(path, readonly=True)
    try:
        return _verify_open(con, path)
    except DAMAGE_ERRORS as exc:
        return damaged_report(path, f"the file is damaged and cannot be checked ({exc!r})")
    finally:
        con.close()


def damaged_report(path: Path, message: str) -> VerifyReport:
    """The report of a file that could not be checked: damaged, with one problem."""
    return VerifyReport(path, False, False, 0, 0, False, [SessionProblem(path, None, message)])


def _verify_open(con: sqlite3.Connection, path: Path) -> VerifyReport:
    try:
        record = record_from(con, path)
    except StudyError as exc:
        return damaged_report(path, str(exc))
    try:
        integrity = con.execute("PRAGMA integrity_check").fetchone()[0]
    except (sqlite3.DatabaseError, ValueError) as exc:
        integrity = repr(exc)
    report = verify_record(record, integrity)
    for difference in tables_match_outbox(path):
        report.problems.append(SessionProblem(path, None, difference))
        report.intact = report.complete = False
    warning = unmerged_wal_warning(path, record)
    if warning:
        report.warnings.append(warning)
    return report


# -- exported zips -------------------------------------------------------------------------


def ratings_csv_name(session_member: str) -> str:
    """The name of the ratings CSV an export puts beside ``session_member``."""
    stem = session_member.removesuffix(SESSION_SUFFIX)
    return "ratings.csv" if stem == "session" else f"{stem}{RATINGS_CSV_SUFFIX}"


def _member_sha256(zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> str:
    digest = hashlib.sha256()
    read = 0
    with zf.open(info) as src:
        while chunk := src.read(1 << 20):
            read += len(chunk)
            if read > MAX_MEMBER_BYTES:
                raise ValueError(f"larger than {MAX_MEMBER_BYTES >> 20} MiB")
            digest.update(chunk)
    return digest.hexdigest()


def export_member_problems(zf: zipfile.ZipFile) -> list[str]:
    """Every member of an exported zip against ``SHA256SUMS``: the sums file missing or
    malformed, a member whose sha256 differs, a member not listed, a listed member missing,
    a name given twice. Session members (``*.sqlite``) are left out: their checksum is
    checked where they are read (:mod:`.sources`), as a fault of the session itself."""
    infos = [i for i in zf.infolist() if not i.is_dir()]
    names = Counter(i.filename for i in infos)
    problems = [f"{name} appears {n} times in the zip" for name, n in names.items() if n > 1]
    if CHECKSUM_MEMBER not in names:
        return [*problems, f"no {CHECKSUM_MEMBER} in the zip, so none of its members can be "
                           "checked against the export"]
    sums: dict[str, str] = {}
    try:
        text = zf.read(CHECKSUM_MEMBER).decode("utf-8", "replace")
    except ZIP_READ_ERRORS as exc:
        return [*problems, f"{CHECKSUM_MEMBER}: unreadable, the zip is damaged ({exc})"]
    for n, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        m = _SUM_LINE.match(line)
        if m is None:
            problems.append(f"{CHECKSUM_MEMBER} line {n} is not '<sha256>  <name>': "
                            f"{line[:60]!r}")
            continue
        sums[m.group(2)] = m.group(1).lower()
    for info in infos:
        name = info.filename
        if name == CHECKSUM_MEMBER or name.endswith(SESSION_SUFFIX):
            continue
        if name not in sums:
            problems.append(f"{name} is in the zip but not listed in {CHECKSUM_MEMBER} "
                            "(added after the export)")
            continue
        try:
            actual = _member_sha256(zf, info)
        except (ValueError, OSError, *ZIP_READ_ERRORS) as exc:
            problems.append(f"{name}: unreadable ({exc})")
            continue
        if actual != sums[name]:
            problems.append(f"{name}: sha256 {actual[:12]}... differs from its "
                            f"{CHECKSUM_MEMBER} entry {sums[name][:12]}... (altered or "
                            "damaged after the export)")
    problems += [f"{name} is listed in {CHECKSUM_MEMBER} but missing from the zip"
                 for name in sums if name not in names]
    return problems


def ratings_csv_problem(zf: zipfile.ZipFile, member: str, session_copy: Path) -> str | None:
    """The zip's ratings CSV against rows regenerated from the session copy (what the
    export wrote), so an edited CSV is caught even with its checksum recomputed."""
    name = ratings_csv_name(member)
    try:
        info = zf.getinfo(name)
    except KeyError:
        return f"holds no ratings CSV {name} (every export has one)"
    if info.file_size > MAX_MEMBER_BYTES:
        return f"{name} is larger than {MAX_MEMBER_BYTES >> 20} MiB"
    try:
        text = zf.read(info).decode("utf-8")
    except UnicodeDecodeError:
        return f"{name} is not UTF-8 text"
    except (OSError, *ZIP_READ_ERRORS) as exc:
        return f"{name}: unreadable ({exc})"
    try:
        rows = read_session(session_copy).ratings
    except StudyError as exc:
        return f"{name} cannot be compared with the session ({exc})"
    difference = ratings_csv_difference(rows, text)
    if difference is None:
        return None
    return f"{name} does not match the session inside the zip ({difference})"


def check_export_copy(report: VerifyReport, zip_path: Path, member: str,
                      session_copy: Path) -> None:
    """Add to ``report`` (of the session ``member``, copied out to ``session_copy``) what is
    wrong with the rest of the exported zip ``zip_path``: members against ``SHA256SUMS``,
    the ratings CSV against the session. Each is damage to the copy (state damaged, exit 2);
    when the session itself verified intact, the message says it stays authoritative."""
    try:
        with zipfile.ZipFile(zip_path) as zf:
            found = export_member_problems(zf)
            csv_problem = ratings_csv_problem(zf, member, session_copy)
    except (OSError, ValueError, *ZIP_READ_ERRORS) as exc:
        found, csv_problem = [f"not a readable zip ({exc})"], None
    missing_csv = f"{ratings_csv_name(member)} is listed in {CHECKSUM_MEMBER} but missing"
    if csv_problem is not None and not (csv_problem.startswith("holds no ratings CSV")
                                        and any(p.startswith(missing_csv) for p in found)):
        found.append(csv_problem)
    if not found:
        return
    verdict = ("the copy is damaged; the session file is intact and authoritative"
               if report.intact else "the copy is damaged")
    report.problems += [SessionProblem(report.path, None, f"{p}: {verdict}") for p in found]
    report.intact = report.complete = False
