"""The only code that changes a session file's tables, one function per kind of change.

Each function takes the change's *body* (plain JSON data: every value it writes, times
included) and applies it inside the caller's transaction. The writer builds bodies from what
the app measured; a study server applies received bodies to rebuild the same file. Either way
the rating chain is checked before a rating row goes in.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable
from typing import Any

from .chain import canonical, genesis, normalise_row, row_hash
from .errors import StudyError
from .records import PlannedTrial
from .schema import CHAINED, DDL, PANEL_DDL, SCHEMA_VERSION, SCREENING_OUTCOMES

Body = dict[str, Any]


def create_tables(con: sqlite3.Connection) -> None:
    from .outbox import OUTBOX_DDL

    for stmt in (DDL + PANEL_DDL + OUTBOX_DDL).split(";"):
        if stmt.strip():
            con.execute(stmt)


def plan_of(body: Body) -> list[PlannedTrial]:
    return [PlannedTrial(int(i), str(s), str(r), int(rep), bool(h))
            for i, s, r, rep, h in body["plan"]]


def _session(con: sqlite3.Connection, body: Body) -> None:
    h = body["header"]
    plan = plan_of(body)
    if [p.index for p in plan] != list(range(len(plan))) or not plan:
        raise StudyError("plan indices must be 0, 1, 2, ... in order")
    con.execute("INSERT INTO meta VALUES ('schema', ?)", (SCHEMA_VERSION,))
    con.execute(
        "INSERT INTO session (session_id, participant, study_id, manifest_sha256, seed,"
        " app_version, created_at, settings, head_hash) VALUES (?,?,?,?,?,?,?,?,?)",
        (h["session_id"], h["participant"], h["study_id"], h["manifest_sha256"], int(h["seed"]),
         h["app_version"], h["created_at"], canonical(body.get("settings") or {}),
         genesis(h, plan)))
    con.executemany("INSERT INTO plan VALUES (?,?,?,?,?,NULL)",
                    [(p.index, p.stimulus, p.reference, p.repetition,
                      int(p.is_hidden_reference)) for p in plan])


def _event_row(con: sqlite3.Connection, at: str, kind: str, details: Body) -> None:
    con.execute("INSERT INTO events (at, kind, details) VALUES (?,?,?)",
                (at, kind, canonical(details)))


def _event(con: sqlite3.Connection, body: Body) -> None:
    _event_row(con, body["at"], body["kind"], body.get("details") or {})


def _preflight(con: sqlite3.Connection, body: Body) -> None:
    results = list(body["results"])
    # Skipped once, skipped for good: trials of that run were shown without a passed check,
    # whatever a later run (resumed without --skip-preflight) finds.
    con.execute("UPDATE session SET preflight=?, "
                "preflight_skipped=MAX(COALESCE(preflight_skipped, 0), ?)",
                (canonical(results), int(bool(body["skipped"]))))
    _event_row(con, body["at"], "preflight", {
        "skipped": bool(body["skipped"]),
        "failed": [r.get("name") for r in results if not r.get("ok")]})


def _start(con: sqlite3.Connection, body: Body) -> None:
    display = body.get("display")
    if display is not None:
        con.execute("UPDATE session SET display=?", (canonical(display),))
    con.execute("UPDATE session SET started_at=COALESCE(started_at, ?)", (body["at"],))
    _event_row(con, body["at"], "start", display or {})


def next_pending(con: sqlite3.Connection) -> sqlite3.Row | None:
    return con.execute(
        "SELECT * FROM plan p WHERE NOT EXISTS (SELECT 1 FROM ratings r WHERE r.trial=p.idx)"
        " AND NOT EXISTS (SELECT 1 FROM plan q WHERE q.requeue_of=p.idx) ORDER BY idx LIMIT 1"
    ).fetchone()


def _presentation(con: sqlite3.Connection, trial: int, outcome: str, body: Body) -> None:
    p = body["presentation"]
    con.execute("INSERT INTO presentations (trial, outcome, details, logged_at) VALUES (?,?,?,?)",
                (trial, outcome, canonical(p["details"]), p["logged_at"]))


def _rating(con: sqlite3.Connection, body: Body) -> None:
    row = normalise_row(body["row"])
    header = con.execute("SELECT n_ratings, head_hash, finished_at FROM session").fetchone()
    nxt = next_pending(con)
    if header["finished_at"] is not None:
        raise StudyError("the session is finished; it accepts no new ratings")
    if nxt is None or nxt["idx"] != row["trial"]:
        raise StudyError(f"trial {row['trial']} is not the next unanswered trial")
    if (nxt["stimulus"], nxt["repetition"]) != (row["stimulus"], row["repetition"]):
        raise StudyError(f"rating of trial {row['trial']} does not match the planned trial")
    if row["seq"] != header["n_ratings"] + 1 or row["prev_hash"] != header["head_hash"]:
        raise StudyError(f"rating {row['seq']} does not continue the rating chain")
    if row_hash(row) != body["row"]["row_hash"]:
        raise StudyError(f"rating {row['seq']}'s content does not match its hash")
    cols = (*CHAINED, "row_hash")
    values = [row[c] if c != "row_hash" else body["row"]["row_hash"] for c in cols]
    con.execute(f"INSERT INTO ratings ({','.join(cols)}) VALUES ({','.join('?' * len(cols))})",
                values)
    con.execute("UPDATE session SET n_ratings=?, head_hash=?", (row["seq"], values[-1]))
    _presentation(con, row["trial"], "rated", body)


def _requeue(con: sqlite3.Connection, body: Body) -> None:
    trial = int(body["trial"])
    nxt = next_pending(con)
    if nxt is None or nxt["idx"] != trial:
        raise StudyError(f"trial {trial} is not the next unanswered trial")
    new_idx = con.execute("SELECT max(idx) + 1 FROM plan").fetchone()[0]
    if int(body["new_idx"]) != new_idx:
        raise StudyError(f"re-queued trial would be {new_idx}, not {body['new_idx']}")
    con.execute("INSERT INTO plan VALUES (?,?,?,?,?,?)",
                (new_idx, nxt["stimulus"], nxt["reference"], nxt["repetition"],
                 nxt["is_hidden_reference"], trial))
    _presentation(con, trial, "requeued", body)


def _close(kind: str) -> Callable[[sqlite3.Connection, Body], None]:
    def close(con: sqlite3.Connection, body: Body) -> None:
        if con.execute("SELECT finished_at FROM session").fetchone()[0] is not None:
            raise StudyError("the session is already closed")
        con.execute("UPDATE session SET finished_at=?", (body["at"],))
        _event_row(con, body["at"], kind, {k: v for k, v in body.items() if k != "at"})
    return close


def _not_withdrawn(con: sqlite3.Connection, what: str) -> None:
    if con.execute("SELECT 1 FROM events WHERE kind='withdrawn'").fetchone() is not None:
        raise StudyError(f"the participant withdrew; the session accepts no {what}")


def _answer(con: sqlite3.Connection, body: Body) -> None:
    """One confirmed answer (also after the last trial: the post-study survey)."""
    _not_withdrawn(con, "answers")
    questionnaire, question = str(body["questionnaire"]), str(body["question"])
    page = int(body["page"])
    ms = body.get("ms")
    if not questionnaire or not question or page < 0:
        raise ValueError("questionnaire, question and page are required")
    if ms is not None and not (isinstance(ms, int | float) and 0 <= ms < 1e9):
        raise ValueError(f"ms must be a non-negative number, got {ms!r}")
    con.execute("INSERT INTO answers (questionnaire, question, value, page, ms, answered_at)"
                " VALUES (?,?,?,?,?,?)", (questionnaire, question, canonical(body["value"]),
                                          page, None if ms is None else float(ms),
                                          str(body["at"])))


def _screening(con: sqlite3.Connection, body: Body) -> None:
    """The result of one vision check."""
    _not_withdrawn(con, "screening results")
    outcome = str(body["outcome"])
    if outcome not in SCREENING_OUTCOMES:
        raise ValueError(f"outcome {outcome!r} is not one of {', '.join(SCREENING_OUTCOMES)}")
    if not isinstance(body["result"], dict):
        raise ValueError("result must be an object")
    con.execute("INSERT INTO screenings (test, outcome, result, at) VALUES (?,?,?,?)",
                (str(body["test"]), outcome, canonical(body["result"]), str(body["at"])))


BLOCK_EVENT = "block"
"""Event kind of a block of trials appended to the plan (adaptive allocation)."""


def _block(con: sqlite3.Connection, body: Body) -> None:
    """A further block of trials (adaptive allocation), appended to the plan once every
    trial planned before it is answered; the block's number, id and issuer go into the
    events, so the study server can check it against the blocks it issued."""
    _not_withdrawn(con, "new trials")
    if con.execute("SELECT finished_at FROM session").fetchone()[0] is not None:
        raise StudyError("the session is finished; it takes no further block")
    if next_pending(con) is not None:
        raise StudyError("a block is added only when every planned trial is answered")
    number = int(body["block"])
    if body["issued_by"] not in ("server", "session"):
        raise ValueError(f"issued_by must be server or session, got {body['issued_by']!r}")
    done = con.execute("SELECT count(*) FROM events WHERE kind=?", (BLOCK_EVENT,)).fetchone()[0]
    if number != done + 2:
        raise StudyError(f"block {number} does not follow block {done + 1}")
    trials = [(str(st), str(ref), int(rep), bool(hidden))
              for st, ref, rep, hidden in body["trials"]]
    if not trials:
        raise ValueError("a block needs at least one trial")
    start = con.execute("SELECT max(idx) + 1 FROM plan").fetchone()[0]
    con.executemany("INSERT INTO plan VALUES (?,?,?,?,?,NULL)",
                    [(start + k, st, ref, rep, int(hidden))
                     for k, (st, ref, rep, hidden) in enumerate(trials)])
    _event_row(con, str(body["at"]), BLOCK_EVENT, {
        "block": number, "id": str(body["id"]), "issued_by": str(body["issued_by"]),
        "first": start, "trials": len(trials)})


APPLY: dict[str, Callable[[sqlite3.Connection, Body], None]] = {
    "block": _block,
    "session": _session,
    "event": _event,
    "preflight": _preflight,
    "start": _start,
    "rating": _rating,
    "requeue": _requeue,
    "finish": _close("finish"),
    "withdrawn": _close("withdrawn"),
    "answer": _answer,
    "screening": _screening,
}


def apply(con: sqlite3.Connection, kind: str, body: Body) -> None:
    """Apply one change; :class:`StudyError` when it does not fit the file's state."""
    fn = APPLY.get(kind)
    if fn is None:
        raise StudyError(f"unknown kind of session change {kind!r}")
    try:
        fn(con, body)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise StudyError(f"malformed {kind} change ({exc!r})") from None
