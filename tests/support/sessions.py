"""Reading a whole session file for comparisons in tests."""

from __future__ import annotations

from pathlib import Path

from session_store.replica import _dump
from session_store.schema import open_existing


def session_tables(path: Path) -> dict[str, list[tuple]]:
    """Every table of a session file as rows (what two copies of a session must share)."""
    con = open_existing(path, readonly=True)
    try:
        return _dump(con)
    finally:
        con.close()
