"""sha256 checksums of stimulus files: compute, verify, report mismatches."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from .errors import StimuliError

_CHUNK = 1 << 20


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            while chunk := fh.read(_CHUNK):
                digest.update(chunk)
    except OSError as exc:
        raise StimuliError(f"cannot read {path} to compute its sha256: {exc.strerror}") from exc
    return digest.hexdigest()


def sha256_path(path: str | Path) -> str:
    """sha256 of a file, or of a frame folder (its sorted file names and contents)."""
    path = Path(path)
    if not path.is_dir():
        return sha256_file(path)
    digest = hashlib.sha256()
    for child in sorted(p for p in path.iterdir() if p.is_file()):
        digest.update(child.name.encode() + b"\0" + bytes.fromhex(sha256_file(child)))
    return digest.hexdigest()


@dataclass(frozen=True)
class ChecksumMismatch:
    """A file whose content does not match the manifest's recorded sha256."""

    stimulus_id: str
    path: Path
    expected: str
    actual: str

    def __str__(self) -> str:
        return (
            f"{self.stimulus_id}: {self.path} has sha256 {self.actual[:12]}..., "
            f"the manifest expects {self.expected[:12]}..."
        )
