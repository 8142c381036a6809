"""Finding session files in what a user names: files, folders and exported zips, many at once.

An exported zip holds ``<participant>_<session>.sqlite`` (older exports: ``session.sqlite``),
the ratings CSV and ``SHA256SUMS``; its members are checked against the sums and copied into a
private temporary folder under names of our own (never the member's path), with a size cap,
so a hostile zip can neither escape the folder nor fill the disk.
"""

from __future__ import annotations

import contextlib
import hashlib
import re
import tempfile
import zipfile
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from .errors import StudyError
from .protocol import PULL_LISTING_FILE
from .records import SessionProblem

CHECKSUM_MEMBER = "SHA256SUMS"
SESSION_SUFFIX = ".sqlite"
MAX_MEMBER_BYTES = 1 << 30  # far above any real session file
_SIDE_SUFFIXES = ("-wal", "-shm", "-journal", ".creating")
#: what reading a damaged zip raises: a bad member header or CRC (BadZipFile), a broken
#: deflate stream (zlib.error), a member cut short (EOFError), a member that is encrypted or
#: packed with a method this Python lacks (RuntimeError, NotImplementedError)
ZIP_READ_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, RuntimeError,
                   NotImplementedError)
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06", b"PK\x07\x08")
_ASK_AGAIN = "ask for the file again (a fresh 'cgvq-study export')"


def damaged_zip_message(detail: str) -> str:
    """The problem text of an exported zip that cannot be read (``detail``: what failed)."""
    return f"damaged zip: {detail}; {_ASK_AGAIN}"


def _looks_like_zip(path: Path) -> bool:
    """A file named ``*.zip`` or starting like one, though :func:`zipfile.is_zipfile` found no
    end-of-archive record in it (a zip cut short in transit)."""
    if path.suffix.lower() == ".zip":
        return True
    try:
        with open(path, "rb") as f:
            return f.read(4) in _ZIP_MAGIC
    except OSError:
        return False


@dataclass
class SessionSource:
    """One session file to read: ``path`` on disk, ``origin`` as the user would name it."""

    path: Path
    origin: str
    problems: list[SessionProblem] = field(default_factory=list)
    """Problems of the container (a zip member failing its checksum)."""
    warnings: list[str] = field(default_factory=list)
    """What could not be checked (a zip without checksums)."""
    container: Path | None = None
    """The exported zip it came from, if any (its other members are checked by
    :func:`session_store.verify.check_export_copy`)."""
    member: str | None = None
    """Its member name in ``container``."""
    name: str = ""
    """Its name relative to the path it was found under: a folder's file by its path inside
    the folder, a file given by itself by its file name, a zip's member as ``zip:member``.
    Unlike ``origin`` it does not depend on where the folder lies or on the working folder,
    so two runs over copies of the same files record the same names."""


def _is_session_name(name: str) -> bool:
    return name.endswith(SESSION_SUFFIX) and not name.endswith(_SIDE_SUFFIXES)


def _read_sums(zf: zipfile.ZipFile, path: Path) -> dict[str, str] | None:
    if CHECKSUM_MEMBER not in zf.namelist():
        return None
    try:
        data = zf.read(CHECKSUM_MEMBER)
    except ZIP_READ_ERRORS as exc:
        raise StudyError(f"{path}: " + damaged_zip_message(
            f"member {CHECKSUM_MEMBER} cannot be read ({exc})")) from None
    sums = {}
    for line in data.decode("utf-8", "replace").splitlines():
        digest, _, name = line.partition("  ")
        if name.strip():
            sums[name.strip()] = digest.strip().lower()
    return sums


def _copy_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, dest: Path, path: Path) -> str:
    """Copy one member of the zip ``path`` to ``dest`` (size-capped); returns its sha256.
    A member that cannot be decompressed is a :class:`StudyError` naming the zip."""
    digest = hashlib.sha256()
    written = 0
    try:
        with zf.open(info) as src, open(dest, "wb") as out:
            while chunk := src.read(1 << 20):
                written += len(chunk)
                if written > MAX_MEMBER_BYTES:
                    raise ValueError(f"member {info.filename} is larger than "
                                     f"{MAX_MEMBER_BYTES >> 20} MiB")
                digest.update(chunk)
                out.write(chunk)
    except ZIP_READ_ERRORS as exc:
        raise StudyError(f"{path}: " + damaged_zip_message(
            f"member {info.filename} cannot be decompressed ({exc})")) from None
    return digest.hexdigest()


def _from_zip(path: Path, name: str, workdir: Path, counter: Iterator[int]
              ) -> tuple[list[SessionSource], list[SessionProblem]]:
    try:
        zf = zipfile.ZipFile(path)
    except (*ZIP_READ_ERRORS, ValueError) as exc:
        return [], [SessionProblem(path, None, damaged_zip_message(f"not a readable zip ({exc})"))]
    except OSError as exc:
        return [], [SessionProblem(path, None, f"not a readable zip ({exc})")]
    sources: list[SessionSource] = []
    problems: list[SessionProblem] = []
    with zf:
        members = [i for i in zf.infolist() if not i.is_dir() and _is_session_name(i.filename)]
        if not members:
            return [], [SessionProblem(path, None, "holds no session file (*.sqlite); send "
                                       "the zip made by 'cgvq-study export'",
                                       nothing_to_check=True)]
        try:
            sums = _read_sums(zf, path)
        except StudyError as exc:
            return [], [SessionProblem(path, None, str(exc).removeprefix(f"{path}: "))]
        for info in members:
            safe = re.sub(r"[^A-Za-z0-9._-]", "_", Path(info.filename).name)
            dest = workdir / f"{next(counter):04d}_{safe}"
            origin = f"{path}:{info.filename}"
            try:
                digest = _copy_member(zf, info, dest, path)
            except StudyError as exc:
                problems.append(SessionProblem(path, None, str(exc).removeprefix(f"{path}: ")))
                continue
            except (ValueError, OSError) as exc:
                problems.append(SessionProblem(path, None, f"{info.filename}: {exc}"))
                continue
            source = SessionSource(dest, origin, container=path, member=info.filename,
                                   name=f"{name}:{info.filename}")
            if sums is None:
                source.warnings.append(f"{origin}: no {CHECKSUM_MEMBER} in the zip, so its "
                                       "integrity in transit cannot be checked")
            elif sums.get(info.filename) != digest:
                source.problems.append(SessionProblem(
                    Path(origin), None, "checksum mismatch: the file was altered or damaged "
                    "in transit"))
            sources.append(source)
    return sources, problems


NOT_FOUND = ("not found; give a session file (.sqlite), an exported .zip or a folder of "
             "them")


def _empty_folder(folder: Path) -> str:
    """Why a folder given holds nothing to read; a pull's folder gets its own reason."""
    if (folder / PULL_LISTING_FILE).is_file():
        return ("no session file in this pull's folder: the server had received no session "
                "when it was pulled")
    return "folder holds no session file (*.sqlite) or exported zip"


@contextlib.contextmanager
def session_sources(paths: Iterable[str | Path]
                    ) -> Iterator[tuple[list[SessionSource], list[SessionProblem]]]:
    """Every session file in ``paths`` (files, folders searched recursively, zips), in a
    stable order, and the problems of what could not be used. Zip members live in a
    temporary folder until the ``with`` block ends."""
    with tempfile.TemporaryDirectory(prefix="cgvq-sessions-") as tmp:
        workdir = Path(tmp)
        counter = iter(range(1 << 30))
        sources: list[SessionSource] = []
        problems: list[SessionProblem] = []
        for given in paths:
            p = Path(given)
            if p.is_dir():
                found = sorted(q for q in p.rglob("*") if q.is_file() and (
                    _is_session_name(q.name) or q.suffix == ".zip"))
                if not found:
                    problems.append(SessionProblem(p, None, _empty_folder(p),
                                                   nothing_to_check=True))
                candidates = found
            elif p.is_file():
                candidates = [p]
            else:
                problems.append(SessionProblem(p, None, NOT_FOUND, nothing_to_check=True))
                continue
            for c in candidates:
                name = c.relative_to(p).as_posix() if p.is_dir() else c.name
                if zipfile.is_zipfile(c):
                    more, bad = _from_zip(c, name, workdir, counter)
                    sources += more
                    problems += bad
                elif _looks_like_zip(c):  # not a SQLite file to try: name the zip's damage
                    problems.append(SessionProblem(c, None, damaged_zip_message(
                        "not a readable zip (truncated or damaged: it has no end-of-archive "
                        "record)")))
                else:
                    sources.append(SessionSource(c, str(c), name=name))
        yield sources, problems
