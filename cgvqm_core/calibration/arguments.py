"""The vocabulary of ``cgvqm calibrate``: option choices and the ``--dataset`` argument.

Kept free of heavy imports (pandas, scipy) so that registering the subcommand in the
``cgvqm`` parser costs nothing for the other subcommands.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import CGVQMError

OBJECTIVES: tuple[str, ...] = ("plcc", "plcc-signed", "nmse")
SELECTIONS: tuple[str, ...] = ("train", "val", "last")
POOLINGS: tuple[str, ...] = ("max", "mean")
ANCHOR_METHODS: tuple[str, ...] = ("logistic", "isotonic")
DMOS_SCALES: tuple[str, ...] = ("quality", "impairment")

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")


@dataclass(frozen=True)
class DatasetSpec:
    """``NAME=MANIFEST:DMOS_CSV`` from the command line."""

    name: str
    manifest: Path
    dmos_csv: Path

    @classmethod
    def parse(cls, text: str) -> DatasetSpec:
        name, eq, rest = text.partition("=")
        cut = _separator(rest)
        if not eq or not _NAME_RE.match(name) or cut is None or cut == 0 or cut == len(rest) - 1:
            raise CGVQMError(
                f"--dataset {text!r}: expected NAME=MANIFEST:DMOS_CSV (NAME of letters, digits, "
                "'_', '-', '.'), e.g. mystudy=study/manifest.json:results/dmos.csv"
            )
        return cls(name, Path(rest[:cut]), Path(rest[cut + 1:]))


def _separator(rest: str) -> int | None:
    """Index of the ':' between the two paths, skipping a Windows drive letter's ("C:\\")."""
    for i, ch in enumerate(rest):
        drive = i == 1 and rest[0].isalpha() and i + 1 < len(rest) and rest[i + 1] in "\\/"
        if ch == ":" and not drive:
            return i
    return None
