"""The hash chain over a session's rating rows.

``row_hash = sha256(prev_hash + canonical JSON of every other chained column)``; the first
row's ``prev_hash`` is the *genesis*: the sha256 of the schema version, the canonical session
header and the original plan. Editing the participant, the plan or any rating breaks the
chain from that row on; a removed tail shows as a mismatch with the header's ``n_ratings`` /
``head_hash``. (A chain recomputed by hand after an edit is not detectable from the file
alone: that is what the study server's acknowledged copy is for.)
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .ratings_csv import tidy_row
from .records import PlannedTrial, SessionProblem
from .schema import CHAINED, INT_COLUMNS, REAL_COLUMNS, SCHEMA_VERSION

GENESIS_HEADER = ("session_id", "participant", "study_id", "manifest_sha256", "seed",
                  "app_version", "created_at")


def canonical(obj: Any) -> str:
    """Canonical JSON (sorted keys, no blanks, no NaN) of what gets hashed or stored."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=False)


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def genesis(header: dict[str, Any], plan: Sequence[PlannedTrial]) -> str:
    """The chain's starting hash: header fields and the original plan."""
    body = {
        "header": {k: header[k] for k in GENESIS_HEADER},
        "plan": [[p.index, p.stimulus, p.reference, p.repetition, int(p.is_hidden_reference)]
                 for p in plan],
    }
    return sha256_text(SCHEMA_VERSION + canonical(body))


def row_hash(row: dict[str, Any]) -> str:
    content = {k: row[k] for k in CHAINED if k != "prev_hash"}
    return sha256_text(row["prev_hash"] + canonical(content))


def normalise_row(row: dict[str, Any]) -> dict[str, Any]:
    """Coerce values to what SQLite returns, so the hash computed on write matches on read."""
    out = dict(row)
    for k in INT_COLUMNS:
        out[k] = int(out[k])
    for k in REAL_COLUMNS:
        if out[k] is not None:
            out[k] = float(out[k])
    return out


def follow_chain(path: Path, header: dict[str, Any], plan: Sequence[PlannedTrial],
                 raw: Sequence[dict[str, Any]], *, first_block_end: int | None = None
                 ) -> tuple[list[dict[str, Any]], list[SessionProblem]]:
    """Check the raw rating rows (in ``seq`` order) against the chain; returns the tidy rows
    up to the first break and the problems found. ``first_block_end``: in an adaptive study,
    the plan index where the blocks appended later begin (they are not in the genesis; each
    rating row still names its stimulus and repetition in the chain)."""
    problems: list[SessionProblem] = []
    by_idx = {p.index: p for p in plan}
    end = len(plan) if first_block_end is None else first_block_end
    original = [p for p in plan if p.requeue_of is None and p.index < end]
    try:
        prev = genesis(header, original)
    except (KeyError, TypeError) as exc:
        return [], [SessionProblem(path, None, f"session record incomplete ({exc})")]
    rows: list[dict[str, Any]] = []
    for expected_seq, r in enumerate(raw, start=1):
        trial = r.get("trial")
        if r["prev_hash"] != prev:
            problems.append(SessionProblem(
                path, trial, "hash chain broken: this row does not follow the previous one "
                "(the session header, plan or an earlier row was edited or removed); rows from "
                "here on are not used"))
            break
        try:
            recomputed = row_hash(normalise_row(r))
        except (KeyError, TypeError, ValueError) as exc:
            problems.append(SessionProblem(path, trial, f"rating row unreadable ({exc})"))
            break
        if recomputed != r["row_hash"]:
            problems.append(SessionProblem(
                path, trial, "hash chain broken: the row's content does not match its hash "
                "(the row was edited); rows from here on are not used"))
            break
        if r["seq"] != expected_seq:
            problems.append(SessionProblem(path, trial, f"sequence number {r['seq']} where "
                                           f"{expected_seq} was expected"))
            break
        p = by_idx.get(trial)
        if p is None or (p.stimulus, p.repetition) != (r["stimulus"], r["repetition"]):
            problems.append(SessionProblem(
                path, trial, "rating row does not match the planned trial"))
            break
        prev = r["row_hash"]
        try:
            rows.append(tidy_row(header, r))
        except (KeyError, TypeError, ValueError) as exc:
            problems.append(SessionProblem(path, trial, f"rating row unreadable ({exc})"))
            break
    else:
        if header["head_hash"] != prev or int(header["n_ratings"]) != len(raw):
            problems.append(SessionProblem(
                path, None, f"the session record counts {header['n_ratings']} rating(s) "
                f"ending in a different hash than the {len(raw)} row(s) present: rating rows "
                "were removed or added outside the app"))
    return rows, problems
