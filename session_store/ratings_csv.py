"""The tidy ratings CSV (the versioned ``cgvq-ratings`` contract) written from session rows."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from stimuli_manifests.tables import RATINGS, write_table

RATINGS_COLUMNS: tuple[str, ...] = RATINGS.required


def write_ratings_csv(rows: Iterable[dict[str, Any]], out: str | Path) -> Path:
    """Write ratings rows (dicts with :data:`RATINGS_COLUMNS`) as the tidy ratings CSV
    (cgvq-ratings/1, docs/file-formats.md)."""
    return write_table(out, RATINGS, rows)
