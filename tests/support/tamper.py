"""Tampering with a session file the way a participant who read the source would."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from session_store.chain import normalise_row, row_hash


def recompute_rating_chain(path: Path, *, seq: int = 2, rating: float = 77.0) -> None:
    """Edit the rating of row ``seq`` and re-hash the rating chain and the header, so the
    chain itself looks intact (only the change log can tell)."""
    con = sqlite3.connect(path)
    con.row_factory = sqlite3.Row
    rows = [dict(r) for r in con.execute("SELECT * FROM ratings ORDER BY seq")]
    prev = rows[0]["prev_hash"]
    for r in rows:
        r["prev_hash"] = prev
        if r["seq"] == seq:
            r["rating"] = rating
        r["row_hash"] = row_hash(normalise_row(r))
        con.execute("UPDATE ratings SET rating=?, prev_hash=?, row_hash=? WHERE seq=?",
                    (r["rating"], r["prev_hash"], r["row_hash"], r["seq"]))
        prev = r["row_hash"]
    con.execute("UPDATE session SET head_hash=?", (prev,))
    con.commit()
    con.close()
