"""Stimulus paths: relative to the manifest's root and never outside it.

Checked twice: lexically (no absolute paths, no ``..``), which works without the files, and
after resolving symlinks when the files exist, so a link that points out of the root is
refused too.
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath, PureWindowsPath

from .errors import ManifestError


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
