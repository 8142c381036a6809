"""The tidy ratings table (the versioned ``cgvq-ratings`` contract): one row per rating, built
from a session's rating row by :func:`tidy_row` (for an export, a reader and the study
server's live frame alike), and written as CSV."""

from __future__ import annotations

import csv
import io
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from stimuli_manifests.tables import RATINGS, RATINGS_1_0, write_table

RATINGS_COLUMNS: tuple[str, ...] = (*RATINGS.required, *RATINGS.optional)


def tidy_row(header: dict[str, Any], r: dict[str, Any]) -> dict[str, Any]:
    """One rating row (a ``ratings`` table row, or a ``rating`` entry's ``row``) of the session
    ``header`` (``study_id``, ``session_id``, ``participant``) as a row of the ratings table
    (:data:`RATINGS_COLUMNS`, in that order)."""
    return {
        "study": header["study_id"],
        "session": header["session_id"],
        "participant": header["participant"],
        "trial": int(r["trial"]),
        "stimulus": r["stimulus"],
        "reference": r["reference"],
        "repetition": int(r["repetition"]),
        "is_hidden_reference": bool(r["is_hidden_reference"]),
        "rating": float(r["rating"]),
        "rt_ms": float(r["rt_ms"]),
        "n_toggles": int(r["n_toggles"]),
        "ms_on_reference": float(r["ms_on_reference"]),
        "ms_on_test": float(r["ms_on_test"]),
        "dropped_frames": int(r["dropped_frames"]),
        "presented_at": r["presented_at"],
        "app_version": r["app_version"],
        "manifest_sha256": header.get("manifest_sha256") or "",
    }


def write_ratings_csv(rows: Iterable[dict[str, Any]], out: str | Path) -> Path:
    """Write ratings rows (dicts with :data:`RATINGS_COLUMNS`) as the tidy ratings CSV
    (cgvq-ratings/1.1, docs/file-formats.md)."""
    return write_table(out, RATINGS, rows, columns=RATINGS.optional)


def _same_cell(got: str, want: str) -> bool:
    """Equal text, or the same number written another way (``55`` and ``55.0``)."""
    if got == want:
        return True
    try:
        return float(got) == float(want)
    except ValueError:
        return False


def ratings_csv_difference(rows: Iterable[dict[str, Any]], text: str) -> str | None:
    """How the ratings CSV ``text`` differs from the one :func:`write_ratings_csv` writes for
    ``rows`` (the same code an export uses), or None when it holds the same values.

    The first differing cell is named (data row, trial, column, both values) with the number
    of differing cells, so that an edited rating is found even when its checksum was redone.
    """
    try:
        got = list(csv.reader(io.StringIO(text.removeprefix("\ufeff"))))
    except csv.Error as exc:
        return f"not a readable CSV file ({exc})"
    # An export written before 1.1 is compared with what 1.0 wrote for the same rows.
    old = bool(got) and got[0] == list(RATINGS_1_0.header(()))
    with tempfile.TemporaryDirectory(prefix="cgvq-ratings-") as tmp:
        target = Path(tmp) / "expected.csv"
        if old:
            write_table(target, RATINGS_1_0, rows)
        else:
            write_ratings_csv(rows, target)
        expected = target.read_text("utf-8")
    want = list(csv.reader(io.StringIO(expected)))
    if not got:
        return "the file is empty"
    if got[0] != want[0]:
        return (f"its columns are {', '.join(got[0])[:120]} instead of "
                f"{', '.join(want[0])[:120]}")
    header = want[0]
    trial = header.index("trial")
    first, n_diff = None, 0
    for i, (g, w) in enumerate(zip(got[1:], want[1:], strict=False), start=1):
        g = g + [""] * (len(header) - len(g))
        for col, gv, wv in zip(header, g, w, strict=False):
            if not _same_cell(gv, wv):
                n_diff += 1
                if first is None:
                    first = (f"row {i} (trial {w[trial]}): {col} {gv or '(empty)'} in the CSV "
                             f"vs {wv or '(empty)'} in the session")
        if len(g) > len(header):
            n_diff += 1
            first = first or f"row {i} (trial {w[trial]}) has {len(g)} cells, not {len(header)}"
    parts = [first] if first else []
    if n_diff > 1:
        parts.append(f"{n_diff} cells differ")
    if len(got) != len(want):
        parts.append(f"{len(got) - 1} rating rows in the CSV, {len(want) - 1} in the session")
    return "; ".join(parts) or None
