"""The CSV contracts of the toolkit (docs/file-formats.md), each with its format version.

One place defines the columns of the ratings, metric-scores and DMOS tables; every writer and
reader goes through it. Each written file carries its format in a last column ``format``
(e.g. ``cgvq-ratings/1``), the same on every row, so the version survives any tool that reads
plain CSV (pandas, R, a spreadsheet). Files without the column are read as version 1 (they
predate the column); a file whose major version differs from the one this toolkit reads is
refused with a message that says so. A minor version may only add optional columns.

Only the standard library is used here, so the participant's base install can write ratings.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import TableError
from .formats import FormatVersionError, VersionedFormat

FORMAT_COLUMN = "format"


@dataclass(frozen=True)
class TableFormat:
    """One CSV contract: its name, version, required and known optional columns."""

    name: str
    major: int
    minor: int
    required: tuple[str, ...]
    optional: tuple[str, ...] = ()
    what: str = ""

    @property
    def versioned(self) -> VersionedFormat:
        """The table's name and version as a :class:`VersionedFormat` (the shared check)."""
        return VersionedFormat(self.name, self.major, self.minor, field=FORMAT_COLUMN,
                               document="table")

    @property
    def version(self) -> str:
        """The value written into the ``format`` column (``name/major`` or ``name/major.minor``)."""
        return self.versioned.version

    @property
    def columns(self) -> tuple[str, ...]:
        """Every known column in the written order (required, optional, ``format``)."""
        return (*self.required, *self.optional, FORMAT_COLUMN)

    def header(self, present: Iterable[str] = ()) -> tuple[str, ...]:
        """Written column order: required, then the known optional and any extra columns
        that are ``present``, then ``format``."""
        present = [c for c in dict.fromkeys(present) if c != FORMAT_COLUMN]
        extra = [c for c in present if c not in self.required and c not in self.optional]
        optional = [c for c in self.optional if c in present]
        return (*self.required, *optional, *extra, FORMAT_COLUMN)

    # -- checking what was read -----------------------------------------------------------
    def check_columns(self, columns: Sequence[str], source: object) -> None:
        """Raise :class:`TableError` when a required column is missing."""
        missing = [c for c in self.required if c not in columns]
        if missing:
            raise TableError(
                f"{source}: not a {self.what or self.name} table: column(s) "
                f"{', '.join(missing)} missing (a {self.version} file has "
                f"{', '.join(self.required)})")

    def check_versions(self, values: Iterable[Any], source: object) -> str:
        """Check the ``format`` values of a file; returns the version read. Every row must
        carry this contract's name and major version."""
        seen = {str(v).strip() for v in values if v is not None and str(v).strip() != ""}
        if not seen:
            return f"{self.name}/{self.major}"
        if len(seen) > 1:
            raise TableError(f"{source}: rows of several formats ({', '.join(sorted(seen))}); "
                             "write one file per format")
        value = seen.pop()
        try:
            self.versioned.check(value)
        except FormatVersionError as exc:
            raise TableError(f"{source}: {exc}") from None
        return value

    def check(self, columns: Sequence[str], format_values: Iterable[Any] | None,
              source: object) -> str:
        """Columns and versions of a table read by any means (csv, pandas)."""
        self.check_columns(columns, source)
        if FORMAT_COLUMN not in columns or format_values is None:
            return f"{self.name}/{self.major}"
        return self.check_versions(format_values, source)


RATINGS = TableFormat(
    "cgvq-ratings", 1, 1,
    required=("study", "session", "participant", "trial", "stimulus", "reference",
              "repetition", "is_hidden_reference", "rating", "rt_ms", "n_toggles",
              "ms_on_reference", "ms_on_test", "dropped_frames", "presented_at",
              "app_version"),
    optional=("manifest_sha256",),  # 1.1: the manifest version the session ran on
    what="ratings",
)
RATINGS_1_0 = TableFormat("cgvq-ratings", 1, 0, required=RATINGS.required, what="ratings")
"""The first ratings table (no ``manifest_sha256``): exports written before 1.1 verify
against it."""

SCORES = TableFormat(
    "cgvq-scores", 1, 1,
    required=("stimulus", "reference", "metric", "score", "direction"),
    optional=("pooling", "patches", "seconds", "backbone", "backbone_sha256",
              "weights_sha256", "settings",
              "title"),  # 1.1: the metric's name as prose and figures print it (PSNR, CGVQM-2)
    what="metric scores",
)
SCORES_1_0 = TableFormat("cgvq-scores", 1, 0, required=SCORES.required,
                         optional=SCORES.optional[:-1], what="metric scores")
"""The first scores table (no ``title``): a run resumed on such a file appends in its layout."""

DMOS = TableFormat(
    "cgvq-dmos", 1, 0,
    required=("stimulus", "reference", "method", "level", "dmos", "ci95_low", "ci95_high",
              "mos", "n_ratings", "model"),
    what="DMOS",
)

ANSWERS = TableFormat(
    "cgvq-answers", 1, 0,
    required=("study", "session", "participant", "questionnaire", "question", "value",
              "answered_at"),
    optional=("page", "ms"),
    what="questionnaire answers",
)

SCREENINGS = TableFormat(
    "cgvq-screenings", 1, 0,
    required=("study", "session", "participant", "test", "outcome", "at"),
    optional=("result",),
    what="vision screening results",
)

DIRECTIONS = ("higher-better", "lower-better")


def write_table(path: str | Path, fmt: TableFormat, rows: Iterable[Mapping[str, Any]], *,
                columns: Sequence[str] | None = None) -> Path:
    """Write ``rows`` as a ``fmt`` table (atomically); ``columns`` (default: the required
    ones) may add optional or extra columns. Every row must hold the required columns; an
    optional or extra column a row lacks is written empty."""
    path = Path(path)
    header = fmt.header(columns or ())
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    try:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(header)
            for row in rows:
                missing = [c for c in fmt.required if c not in row]
                if missing:
                    raise TableError(f"{path}: a row lacks column {missing[0]!r}")
                writer.writerow([fmt.version if c == FORMAT_COLUMN else row.get(c, "")
                                 for c in header])
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(path)
    return path


def read_table(path: str | Path, fmt: TableFormat) -> list[dict[str, str]]:
    """Rows of a ``fmt`` table as dicts of strings (without ``format``); checks the columns
    and the format version."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            columns = list(reader.fieldnames or ())
            rows = list(reader)
    except UnicodeDecodeError:
        raise TableError(f"{path}: not a UTF-8 text CSV file") from None
    except csv.Error as exc:
        raise TableError(f"{path}: not a readable CSV file ({exc})") from None
    fmt.check(columns, [r.get(FORMAT_COLUMN) for r in rows], path)
    for r in rows:
        r.pop(FORMAT_COLUMN, None)
    return rows
