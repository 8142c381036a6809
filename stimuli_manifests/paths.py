"""Stimulus paths: relative to the manifest's root and never outside it.

Checked twice: lexically (no absolute paths, no ``..``), which works without the files, and
after resolving symlinks when the files exist, so a link that points out of the root is
refused too.
"""

from __future__ import annotations

import re
from pathlib import Path, PurePosixPath, PureWindowsPath

from .errors import ManifestError

#: Characters no file name may hold on Windows (``:`` would also restart a path on a drive).
UNSAFE_CHARS = re.compile(r'[\x00-\x1f<>:"|?*\\]')
#: Device names Windows refuses as a file or folder name, with any extension.
WINDOWS_RESERVED = frozenset({"con", "prn", "aux", "nul", *(f"com{i}" for i in range(10)),
                              *(f"lpt{i}" for i in range(10))})


def portable_part_problem(part: str) -> str | None:
    """Why one path segment would not name the same file on every participant's system
    (None: it would): Windows' forbidden characters, a trailing dot or space (dropped
    there), a reserved device name (CON, AUX, NUL...), or ``.``/``..``/empty."""
    if part in ("", ".", ".."):
        return "is empty, '.' or '..'"
    if (m := UNSAFE_CHARS.search(part)) is not None:
        return f"holds {m.group(0)!r}, which a Windows file name cannot"
    if part.endswith((".", " ")):
        return "ends in a dot or a space, which Windows drops"
    if part.split(".")[0].strip().lower() in WINDOWS_RESERVED:
        return "is a device name Windows reserves"
    return None


def check_relative(path: str, *, field: str) -> PurePosixPath:
    """Refuse absolute paths, drive letters, backslashes and ``..`` components."""
    if not path or not path.strip():
        raise ManifestError(f"{field}: path is empty")
    if "\\" in path or PureWindowsPath(path).drive:
        raise ManifestError(f"{field}: {path!r} must use '/' separators and no drive letter")
    pure = PurePosixPath(path)
    if pure.is_absolute():
        raise ManifestError(f"{field}: {path!r} is absolute; paths must be relative to the root")
    if ".." in pure.parts:
        raise ManifestError(f"{field}: {path!r} contains '..' and could leave the root")
    for part in path.split("/"):
        if part and (why := portable_part_problem(part)) is not None:
            raise ManifestError(f"{field}: {path!r}: {part!r} {why}; every participant's "
                                "download refuses it, so rename it")
    return pure


def resolve_inside(root: Path, path: str, *, field: str) -> Path:
    """Absolute location of ``path`` under ``root``; refuses anything that escapes it."""
    pure = check_relative(path, field=field)
    candidate = root / Path(*pure.parts)
    real_root = root.resolve()
    real = candidate.resolve()
    if not real.is_relative_to(real_root):
        raise ManifestError(
            f"{field}: {path!r} resolves to {real}, outside the root {real_root} "
            "(a symlink leaves the root)"
        )
    return candidate
