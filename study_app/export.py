"""One file to send back: a zip holding a consistent copy of the session file and its sha256.

The copy is made with SQLite's backup API (so it is consistent even while the WAL holds
uncommitted pages) and switched to a single-file journal, so the returned file needs no side
files. :func:`verify_file` accepts the zip or a bare session file.
"""

from __future__ import annotations

import hashlib
import sqlite3
import tempfile
import zipfile
from pathlib import Path

from .errors import StudyError
from .session import VerifyReport, read_info, read_ratings, verify_session, write_ratings_csv

SESSION_MEMBER = "session.sqlite"
CHECKSUM_MEMBER = "SHA256SUMS"
CSV_MEMBER = "ratings.csv"


def _snapshot(src: Path, dest: Path) -> None:
    source = sqlite3.connect(f"{src.resolve().as_uri()}?mode=ro", uri=True)
    target = sqlite3.connect(dest)
    try:
        source.backup(target)
        target.execute("PRAGMA journal_mode=DELETE")
        target.commit()
    finally:
        target.close()
        source.close()


def export_session(path: str | Path, out: str | Path | None = None) -> Path:
    """Write ``<participant>_<session>.zip`` (session copy, ratings CSV, SHA256SUMS)."""
    path = Path(path)
    info = read_info(path)
    if out is None:
        out = path.with_name(f"{info.participant}_{info.session_id}.zip")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / SESSION_MEMBER
        _snapshot(path, copy)
        rows, _ = read_ratings(copy)
        csv_path = write_ratings_csv(rows, Path(tmp) / CSV_MEMBER)
        sums = "".join(f"{hashlib.sha256(p.read_bytes()).hexdigest()}  {p.name}\n"
                       for p in (copy, csv_path))
        part = out.with_name(out.name + ".part")
        with zipfile.ZipFile(part, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            zf.write(copy, SESSION_MEMBER)
            zf.write(csv_path, CSV_MEMBER)
            zf.writestr(CHECKSUM_MEMBER, sums)
        part.replace(out)
    return out


def verify_file(path: str | Path) -> VerifyReport:
    """Verify a returned file: an exported zip (checksums first) or a session file."""
    path = Path(path)
    if not path.is_file():
        raise StudyError(f"file not found: {path}")
    if not zipfile.is_zipfile(path):
        return verify_session(path)
    with zipfile.ZipFile(path) as zf, tempfile.TemporaryDirectory() as tmp:
        names = set(zf.namelist())
        if SESSION_MEMBER not in names or CHECKSUM_MEMBER not in names:
            raise StudyError(f"{path} is not an exported session (it lacks {SESSION_MEMBER} "
                             f"or {CHECKSUM_MEMBER}); send the file made by 'cgvq-study export'")
        expected = {}
        for line in zf.read(CHECKSUM_MEMBER).decode("utf-8", "replace").splitlines():
            digest, _, name = line.partition("  ")
            expected[name.strip()] = digest.strip()
        bad = [name for name, digest in expected.items()
               if name not in names or hashlib.sha256(zf.read(name)).hexdigest() != digest]
        zf.extract(SESSION_MEMBER, tmp)
        report = verify_session(Path(tmp) / SESSION_MEMBER)
        report.path = path
        if bad:
            from .session import SessionProblem

            report.problems.insert(0, SessionProblem(
                path, None, f"checksum mismatch for {', '.join(bad)}: the file was altered or "
                "damaged in transit"))
            report.intact = False
            report.complete = False
        return report
