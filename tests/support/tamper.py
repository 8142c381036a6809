"""Editing database files behind their owner's back, the way a participant who read the
source would: plain SQL edits, and a forger who re-hashes the chains so they look intact."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import sqlite3
import zipfile
from collections.abc import Callable
from pathlib import Path

from session_store.chain import canonical, normalise_row, row_hash
from session_store.outbox import entry_hash


def edit_database(path: Path, *statements: str) -> None:
    """Run ``statements`` on the SQLite file at ``path`` and commit them."""
    con = sqlite3.connect(path)
    for statement in statements:
        con.execute(statement)
    con.commit()
    con.close()


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


def rewrite_change_log(path: Path, edit: Callable[[str, dict], None]) -> None:
    """Let ``edit(kind, body)`` change the body of every change-log (outbox) entry in place,
    then re-hash the whole log, so that its own chain looks intact."""
    con = sqlite3.connect(path)
    rows = con.execute("SELECT seq, kind, body, prev_hash FROM outbox ORDER BY seq").fetchall()
    prev = None
    for seq, kind, text, prev_hash in rows:
        body = json.loads(text)
        edit(kind, body)
        prev = prev_hash if prev is None else prev
        digest = entry_hash(prev, seq, kind, body)
        con.execute("UPDATE outbox SET body=?, prev_hash=?, entry_hash=? WHERE seq=?",
                    (canonical(body), prev, digest, seq))
        prev = digest
    con.commit()
    con.close()


def rewrite_zip(path: Path, edit: Callable[[dict[str, bytes]], None], *,
                resum: bool = False) -> None:
    """Let ``edit(members)`` change an exported zip's ``{name: bytes}`` (edit, add or delete
    members), then write the zip again; ``resum=True`` also recomputes SHA256SUMS over every
    other member, as a forger who read the export code would."""
    with zipfile.ZipFile(path) as zf:
        members = {name: zf.read(name) for name in zf.namelist()}
    edit(members)
    if resum:
        members["SHA256SUMS"] = "".join(
            f"{hashlib.sha256(data).hexdigest()}  {name}\n"
            for name, data in members.items() if name != "SHA256SUMS").encode()
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)


def edit_csv_cell(data: bytes, row: int, column: str, value: str) -> bytes:
    """The CSV ``data`` with data row ``row`` (1 = the first after the header) of ``column``
    set to ``value``."""
    rows = list(csv.reader(io.StringIO(data.decode("utf-8"))))
    rows[row][rows[0].index(column)] = value
    out = io.StringIO()
    csv.writer(out).writerows(rows)
    return out.getvalue().encode("utf-8")
