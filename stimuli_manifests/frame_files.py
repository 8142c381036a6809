"""The order of a folder of numbered PNG frames.

Renderers number frames without zero-padding as often as with it (``frame_9.png``,
``frame_10.png``), so the order is the number in each name, never the alphabet: read
alphabetically, ``frame_10`` would come before ``frame_2`` and every score would be computed
on shuffled frames without a word. A folder whose names do not give one unbroken run of
numbers is refused rather than guessed.
"""

from __future__ import annotations

import re
from pathlib import Path

from .errors import VideoError

_LAST_NUMBER = re.compile(r"(\d+)(?!.*\d)")


def frame_number(path: Path) -> int | None:
    """The last run of digits in the file's stem (``shot2_0042`` -> 42), or None."""
    match = _LAST_NUMBER.search(path.stem)
    return int(match.group(1)) if match else None


def ordered_frames(folder: Path) -> list[Path]:
    """The folder's ``.png`` files in frame order: by the number in each name, which must be
    unique and run without gaps. A folder of one frame needs no number."""
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png" and p.is_file())
    if len(files) <= 1:
        return files
    numbered: dict[int, Path] = {}
    for path in files:
        number = frame_number(path)
        if number is None:
            raise VideoError(f"{folder}: frame file {path.name} has no frame number; name "
                             "every frame with its number (e.g. frame_0001.png)")
        if number in numbered:
            raise VideoError(f"{folder}: {numbered[number].name} and {path.name} both carry "
                             f"frame number {number}")
        numbered[number] = path
    first, last = min(numbered), max(numbered)
    missing = [n for n in range(first, last + 1) if n not in numbered]
    if missing:
        shown = ", ".join(str(n) for n in missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise VideoError(f"{folder}: frames {first}..{last} have {len(missing)} missing "
                         f"number(s) ({shown}); a missing frame would shorten the video")
    return [numbered[n] for n in range(first, last + 1)]
