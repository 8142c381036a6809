"""The tidy ratings table (the versioned ``cgvq-ratings`` contract): one row per rating, built
from a session's rating row by :func:`tidy_row` (for an export, a reader and the study
server's live frame alike), and written as CSV."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from stimuli_manifests.tables import RATINGS, write_table

RATINGS_COLUMNS: tuple[str, ...] = RATINGS.required


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
    }


def write_ratings_csv(rows: Iterable[dict[str, Any]], out: str | Path) -> Path:
    """Write ratings rows (dicts with :data:`RATINGS_COLUMNS`) as the tidy ratings CSV
    (cgvq-ratings/1, docs/file-formats.md)."""
    return write_table(out, RATINGS, rows)
