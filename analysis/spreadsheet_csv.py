"""CSV files as spreadsheets write them, read into stripped text cells.

Researchers edit ratings and metric scores in spreadsheets, which save CSV with the locale's
habits: semicolons or tabs between columns where the decimal mark is a comma, a byte-order
mark, column names in another case, trailing empty cells. Every analysis input in CSV reads
through :func:`read_cells`, so each is held to the same rules and the same messages.
"""

from __future__ import annotations

import re
import warnings
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import AnalysisError

_DECIMAL_COMMA = re.compile(r"[-+]?\d+,\d+")


def read_cells(path: Path, *, what: str, columns: Sequence[str],
               decimals: Sequence[str] = ()) -> pd.DataFrame:
    """``path`` (plain or compressed, as pandas infers from the name) as text cells, with
    ``_source``/``_row`` naming each row for messages (``_row``: its line in the file).

    Commas, or semicolons or tabs between columns (the header decides); the names of
    ``columns`` in any case; cells without surrounding spaces; empty lines and rows of empty
    cells (Excel's trailing ``,,``) skipped; decimal commas in ``decimals`` read as points
    where the columns are not comma-separated. ``what`` names the file in messages
    (``ratings file``)."""
    header = _read(path, ",", what, header_only=True).columns
    sep = _other_separator(str(header[0])) if len(header) == 1 else None
    frame = _read(path, sep or ",", what)
    frame = frame.rename(columns=_known_names(frame.columns, columns))
    frame["_source"] = str(path)
    frame["_row"] = np.arange(len(frame)) + 2  # line number: header is line 1
    data = [c for c in frame.columns if not str(c).startswith("_")]
    for c in data:
        if frame[c].dtype == object or pd.api.types.is_string_dtype(frame[c]):
            frame[c] = frame[c].astype(object).where(frame[c].notna(), "").map(str).str.strip()
    frame = frame.loc[~(frame[data].astype(str) == "").all(axis=1)]
    frame.attrs["sep"] = sep or ","
    read_decimal_commas(frame, path, what, decimals)
    return frame


def _read(path: Path, sep: str, what: str, *, header_only: bool = False) -> pd.DataFrame:
    """The file as text cells; rows with more cells than the header are refused (pandas
    would otherwise take the first column as an index, or drop the extra cells)."""
    _refuse_a_session_file(path, what)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", pd.errors.ParserWarning)
            frame = pd.read_csv(path, sep=sep, dtype=str, keep_default_na=False,
                                skip_blank_lines=False, index_col=False,
                                nrows=0 if header_only else None)
    except pd.errors.ParserWarning:
        raise AnalysisError(
            f"{what} {path}: its rows have more cells than its header; a decimal comma "
            "or a comma inside an id? Quote such cells, or save the file with ';' between "
            "columns") from None
    except FileNotFoundError:
        raise AnalysisError(f"{what} {path} does not exist") from None
    except UnicodeDecodeError as exc:
        raise AnalysisError(f"{what} {path} is not UTF-8 text ({exc}); save it as "
                            "'CSV UTF-8'") from None
    except pd.errors.EmptyDataError:
        raise AnalysisError(f"{what} {path} is empty: not even a header line") from None
    except (pd.errors.ParserError, ValueError, EOFError, OSError, zlib.error) as exc:
        hint = ("; a decimal comma or a comma inside an id? Quote such cells, or save the "
                "file with ';' between columns" if "Expected" in str(exc) else "")
        raise AnalysisError(f"{what} {path} is not a readable CSV "
                            f"({' '.join(str(exc).split())}){hint}") from None
    frame.columns = [str(c).strip().lstrip("\ufeff") for c in frame.columns]
    return frame


def _refuse_a_session_file(path: Path, what: str) -> None:
    """A session file given as a CSV: say where it belongs (its bytes read as a CSV
    gave "not a readable CSV ... a decimal comma?")."""
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError:
        return  # the reader says what is wrong with it
    if head == b"SQLite format 3\x00":
        raise AnalysisError(f"{what} {path} is a session file, not a CSV: give it (or "
                            "its folder) to --sessions")


def _other_separator(header: str) -> str | None:
    """The separator a one-column header shows it was written with (';' or tab)."""
    found = [s for s in ";\t" if s in header]
    return max(found, key=header.count) if found else None


def _known_names(columns: Sequence[str], known_columns: Sequence[str]) -> dict[str, str]:
    """Columns named as the table's but in another case (``Participant``), renamed."""
    known = {c.lower(): c for c in known_columns}
    taken = set(columns)
    out: dict[str, str] = {}
    for c in columns:
        name = known.get(c.lower())
        if name is not None and name not in taken:
            out[c] = name
            taken.add(name)
    return out


def read_decimal_commas(frame: pd.DataFrame, path: Path, what: str,
                        columns: Sequence[str]) -> None:
    """Numbers written with a decimal comma (``2,5``) in ``columns`` of a frame
    :func:`read_cells` read: read as such in a file whose columns are separated otherwise
    (spreadsheets in many locales); refused in a comma-separated one, where a comma is what
    separates columns."""
    comma_separated = frame.attrs.get("sep", ",") == ","
    for column in columns:
        if column not in frame.columns:
            continue
        cells = frame[column].astype(str)
        comma = cells.str.fullmatch(_DECIMAL_COMMA).to_numpy()
        if not comma.any():
            continue
        if comma_separated:
            first = int(np.flatnonzero(comma)[0])
            raise AnalysisError(
                f"{what} {path}: {int(comma.sum())} {column}(s) are written with a "
                f"decimal comma (line {frame['_row'].iloc[first]}: {cells.iloc[first]!r}); "
                "write decimals with a point (2.5), or save the file with ';' between "
                "columns")
        frame.loc[comma, column] = cells[comma].str.replace(",", ".", regex=False)
