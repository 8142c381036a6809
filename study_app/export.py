"""One file to send back: a zip holding a consistent copy of the session file and its sha256.

The copy is made with SQLite's backup API (so it holds everything committed, the WAL
included) and switched to a single-file journal, so the returned file needs no side files.
Names are unique per participant and session, file and member alike
(``<participant>_<session>.zip`` holding ``<participant>_<session>.sqlite``), so twenty returns
unzipped into one folder never overwrite each other. :func:`verify_file` accepts the zip or a
bare session file.
"""

from __future__ import annotations

import csv
import hashlib
import sqlite3
import tempfile
import zipfile
from dataclasses import replace
from pathlib import Path

from session_store import (
    SessionProblem,
    VerifyReport,
    check_participant_id,
    read_session,
    session_sources,
    verify_record,
    verify_session,
    write_ratings_csv,
)
from session_store.errors import StudyError
from session_store.schema import DAMAGE_ERRORS, open_existing
from session_store.sources import CHECKSUM_MEMBER
from session_store.verify import check_export_copy

CSV_SUFFIX = "_ratings.csv"


def _snapshot(src: Path, dest: Path) -> None:
    """Copy ``src`` with everything committed (its ``-wal`` folded in, from a read-only
    folder too) into ``dest``; a file damaged beyond copying is a :class:`StudyError`."""
    source = open_existing(src, readonly=True)
    try:
        target = sqlite3.connect(dest)
        try:
            source.backup(target)
            target.execute("PRAGMA journal_mode=DELETE")
            target.commit()
        finally:
            target.close()
    except DAMAGE_ERRORS as exc:
        raise StudyError(f"{src} cannot be copied, it is damaged ({exc!r}); send the file "
                         "itself as it is") from None
    finally:
        source.close()


def export_name(path: str | Path) -> str:
    """``<participant>_<session>`` of a session file; refuses ids that are not valid ids
    (a file edited outside the app must not choose where its export is written)."""
    info = read_session(path).info
    try:
        check_participant_id(info.participant)
    except StudyError as exc:
        raise StudyError(f"{path}: {exc}; this file was not written by cgvq-study as it "
                         "is") from None
    session = "".join(c for c in info.session_id if c.isalnum())[:32] or "session"
    return f"{info.participant}_{session}"


def export_target(out: str | Path | None, stem: str) -> Path:
    """Where :func:`export_session` writes: ``out`` if it names a .zip, else
    ``<out>/<stem>.zip`` for a folder (the current one by default). Refuses (StudyError)
    a path with another extension, and an existing file that is not an export of the same
    session (a zip this command wrote may be replaced by a newer export)."""
    if out is None:
        out = Path.cwd()
    out = Path(out)
    if not out.is_dir():
        if out.exists() and out.suffix.lower() != ".zip":
            raise StudyError(f"--out {out} is an existing file, not a .zip or a folder; give a "
                             "new .zip path or a folder")
        if out.suffix and out.suffix.lower() != ".zip":
            raise StudyError(f"--out {out}: an export is a .zip file; give a path ending in "
                             ".zip, or a folder (without an extension) to write "
                             f"{stem}.zip into")
    if out.is_dir() or out.suffix.lower() != ".zip":  # a folder, made if need be
        out = out / f"{stem}.zip"
    for parent in (out.parent, *out.parent.parents):
        if parent.exists():
            if not parent.is_dir():
                raise StudyError(f"--out {out}: {parent} is a file, not a folder")
            break
    if out.is_dir():
        raise StudyError(f"--out {out} is a folder; give a new .zip path")
    if out.exists() and not _is_export_of(out, stem):
        raise StudyError(f"--out {out} exists and is not an export of this session; choose "
                         "another --out (an existing file is replaced only by a newer export "
                         "of the same session)")
    return out


def _is_export_of(path: Path, stem: str) -> bool:
    """Whether ``path`` is a zip :func:`export_session` wrote for the session ``stem``."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
    except (zipfile.BadZipFile, OSError):
        return False
    return names == {f"{stem}.sqlite", f"{stem}{CSV_SUFFIX}", CHECKSUM_MEMBER}


def check_ratings_csv_target(out: str | Path) -> Path:
    """``--csv OUT`` before anything is written: a new file, or a ratings CSV written before
    (its header is the tidy ratings CSV's), never some other file."""
    from stimuli_manifests.tables import RATINGS, RATINGS_1_0

    out = Path(out)
    if out.is_dir():
        raise StudyError(f"--csv {out} is a folder; give the path of a CSV file")
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                raise StudyError(f"--csv {out}: {parent} is a file, not a folder")
            break
    if out.exists():
        try:
            with open(out, newline="", encoding="utf-8-sig") as fh:
                header = next(csv.reader(fh), [])
        except (OSError, UnicodeDecodeError, csv.Error):
            header = []
        if header not in (list(RATINGS.header(RATINGS.optional)),
                          list(RATINGS_1_0.header(()))):
            raise StudyError(f"--csv {out} exists and is not a ratings CSV; choose another "
                             "--csv (only a ratings CSV written before is replaced)")
    return out


def export_session(path: str | Path, out: str | Path | None = None) -> Path:
    """Write ``<participant>_<session>.zip`` (session copy, ratings CSV, SHA256SUMS) to
    ``out``: a path ending in .zip, or a folder (made if needed; default the current one)."""
    path = Path(path)
    stem = export_name(path)
    out = export_target(out, stem)
    out.parent.mkdir(parents=True, exist_ok=True)
    member = f"{stem}.sqlite"
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / member
        _snapshot(path, copy)
        csv_path = write_ratings_csv(read_session(copy).ratings, Path(tmp) / f"{stem}{CSV_SUFFIX}")
        sums = "".join(f"{hashlib.sha256(p.read_bytes()).hexdigest()}  {p.name}\n"
                       for p in (copy, csv_path))
        part = out.with_name(out.name + ".part")
        with zipfile.ZipFile(part, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            zf.write(copy, member)
            zf.write(csv_path, csv_path.name)
            zf.writestr(CHECKSUM_MEMBER, sums)
        part.replace(out)
    return out


def verify_file(path: str | Path) -> VerifyReport:
    """Verify one returned file: an exported zip (checksums first) or a session file."""
    path = Path(path)
    if not path.is_file():
        raise StudyError(f"file not found: {path}")
    if not zipfile.is_zipfile(path):
        return verify_session(path)
    reports = verify_many([path])
    if len(reports) != 1:
        raise StudyError(f"{path} holds {len(reports)} session files; verify lists each")
    return reports[0]


def verify_many(paths: list[str | Path]) -> list[VerifyReport]:
    """Verify every session file in ``paths`` (files, folders, zips); one report each, the
    problems of unusable inputs as damaged reports of their own.

    A session from an exported zip is also checked as a copy: every member against
    ``SHA256SUMS`` and the ratings CSV against the session (a fault there is damage, exit 2;
    the session file stays the authority)."""
    reports: list[VerifyReport] = []
    with session_sources(paths) as (sources, problems):
        for problem in problems:
            reports.append(VerifyReport(problem.path, False, False, 0, 0, False, [problem]))
        for source in sources:
            try:
                report = verify_session(source.path)
            except (StudyError, *DAMAGE_ERRORS) as exc:  # one bad file never stops the rest
                reports.append(VerifyReport(Path(source.origin), False, False, 0, 0, False,
                                            [SessionProblem(Path(source.origin), None,
                                                            str(exc))]))
                continue
            if source.origin != str(source.path):  # a zip member: name it as the user does
                origin = Path(source.origin)
                report.problems = [replace(q, path=origin) if q.path == source.path else q
                                   for q in report.problems]
                report.warnings = [w.replace(str(source.path), source.origin)
                                   for w in report.warnings]
                report.path = origin
            # a zip member's warning (no SHA256SUMS) is a problem of the copy, checked below
            if source.container is None:
                report.warnings[:0] = source.warnings
            if source.problems:
                report.problems[:0] = source.problems
                report.intact = report.complete = False
            if source.container is not None and source.member is not None:
                check_export_copy(report, source.container, source.member, source.path)
            reports.append(report)
    return reports


__all__ = ["export_name", "export_session", "verify_file", "verify_many", "verify_record"]
