"""What an uploaded entry may contain: its JSON types, and its fit with the study.

The replica's mutations check the chain and the order of the ratings, not what a body holds:
a plan of one stimulus fifty times, a rating of -1 000 000 on a 0..100 scale or ``settings``
that is a list would be stored as sent, feed the statistics, the stopping rule and ``pull``,
and (for the wrong types) make the statistics fail for everyone. So each entry is checked
here, before it is applied, against what the app itself writes (:mod:`session_store.writer`)
and against the study version the session is pinned to (:class:`StudyDesign`):

- types: ``settings``, ``display``, ``details``, ``result`` are objects, times are ISO
  strings, the plan and rating columns have their types, numbers are finite;
- design: plan rows and block trials name stimuli of the study with their own reference and
  hidden-reference flag; the first plan holds every stimulus equally often, ``repetitions``
  times (once in an adaptive study; a simulated session may use its own ``--repetitions``);
  block entries only in adaptive studies; ratings lie within the scale.

Every problem is one line that names the entry and the field, never a client's free text.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from session_store.outbox import OutboxEntry
from session_store.schedule import ScheduleItem, schedule_items
from stimuli_manifests import Manifest

MAX_INT = 2**62
"""Larger integers do not fit SQLite's 64-bit integers (an OverflowError before)."""
MAX_TEXT = 200
"""Longest id-like string (stimulus, reference, kind, test...)."""
MAX_REPETITIONS = 100
"""The manifest's own limit on ``protocol.repetitions``."""

ROW_INTS = ("seq", "trial", "repetition", "is_hidden_reference", "n_toggles",
            "frames_presented", "dropped_frames")
ROW_REALS = ("rating", "rt_ms", "ms_on_reference", "ms_on_test", "max_flip_interval_ms")
ROW_TEXTS = ("stimulus", "reference", "switch_latencies_ms", "presented_at", "answered_at",
             "app_version", "prev_hash", "row_hash")


class BadContent(ValueError):  # noqa: N818 (a reason to refuse, not a bug)
    """An entry whose content does not fit its kind or the study (refused with 422)."""


@dataclass(frozen=True)
class StudyDesign:
    """What uploads are checked against: one study version's stimuli, scale and protocol."""

    items: dict[str, ScheduleItem]
    repetitions: int
    adaptive: bool
    scale: tuple[float, float]
    panel: Any

    @classmethod
    def of(cls, m: Manifest) -> StudyDesign:
        items = {it.id: it for it in schedule_items(m)}
        return cls(items, m.protocol.repetitions, m.protocol.allocation == "adaptive",
                   (float(m.scale.min), float(m.scale.max)), m.panel)


# -- JSON types -------------------------------------------------------------------------
def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and -MAX_INT <= x <= MAX_INT


def _is_num(x: Any) -> bool:
    return (isinstance(x, int | float) and not isinstance(x, bool)
            and math.isfinite(x) and abs(x) <= MAX_INT)


def _need(ok: bool, where: str, what: str) -> None:
    if not ok:
        raise BadContent(f"{where} must be {what}")


def _text(x: Any, where: str, limit: int = MAX_TEXT) -> None:
    _need(isinstance(x, str) and len(x) <= limit, where, f"a string of at most {limit} "
          "characters")


def parse_time(text: Any) -> datetime | None:
    """An ISO 8601 time as aware UTC, or None when it is not one."""
    if not isinstance(text, str) or len(text) > 40:
        return None
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
        return t.astimezone(UTC) if t.tzinfo else t.replace(tzinfo=UTC)
    except (ValueError, OverflowError):  # e.g. year 9999 at -23:59 leaves the range
        return None


def _time(x: Any, where: str) -> None:
    _need(parse_time(x) is not None, where, "an ISO 8601 time")


def _object(x: Any, where: str, *, optional: bool = False) -> None:
    _need(isinstance(x, dict) or (optional and x is None), where,
          "a JSON object" + (" or null" if optional else ""))


def _session_shape(b: dict[str, Any]) -> None:
    h = b.get("header")
    _object(h, "header")
    for k in ("session_id", "participant", "study_id", "app_version"):
        _text(h.get(k), f"header.{k}")
    _need(h.get("manifest_sha256") is None or isinstance(h.get("manifest_sha256"), str),
          "header.manifest_sha256", "a string")
    _need(_is_int(h.get("seed")), "header.seed", "an integer")
    _time(h.get("created_at"), "header.created_at")
    _object(b.get("settings"), "settings", optional=True)
    plan = b.get("plan")
    _need(isinstance(plan, list) and bool(plan), "plan", "a non-empty list")
    for k, row in enumerate(plan):
        _need(isinstance(row, list) and len(row) == 5 and _is_int(row[0])
              and isinstance(row[1], str) and isinstance(row[2], str) and _is_int(row[3])
              and row[4] in (0, 1), f"plan row {k}",
              "[index, stimulus, reference, repetition, hidden 0/1]")


def _presentation_shape(p: Any) -> None:
    _object(p, "presentation")
    _object(p.get("details"), "presentation.details")
    _time(p.get("logged_at"), "presentation.logged_at")


def _rating_shape(b: dict[str, Any]) -> None:
    row = b.get("row")
    _object(row, "row")
    for k in ROW_INTS:
        _need(_is_int(row.get(k)) and row[k] >= 0, f"row.{k}", "a non-negative integer")
    for k in ROW_REALS:
        _need(_is_num(row.get(k)), f"row.{k}", "a finite number")
    for k in ("rt_ms",):
        _need(row[k] >= 0, f"row.{k}", "not negative")
    _need(row.get("slider_first_move_ms") is None or _is_num(row["slider_first_move_ms"]),
          "row.slider_first_move_ms", "a finite number or null")
    for k in ROW_TEXTS:
        _text(row.get(k), f"row.{k}", 100_000 if k == "switch_latencies_ms" else MAX_TEXT)
    _time(row["presented_at"], "row.presented_at")
    _time(row["answered_at"], "row.answered_at")
    _presentation_shape(b.get("presentation"))


def _requeue_shape(b: dict[str, Any]) -> None:
    for k in ("trial", "new_idx"):
        _need(_is_int(b.get(k)) and b[k] >= 0, k, "a non-negative integer")
    _presentation_shape(b.get("presentation"))


def _block_shape(b: dict[str, Any]) -> None:
    _need(_is_int(b.get("block")), "block", "an integer")
    _text(b.get("id"), "id")
    _text(b.get("issued_by"), "issued_by")
    trials = b.get("trials")
    _need(isinstance(trials, list) and bool(trials), "trials", "a non-empty list")
    for k, t in enumerate(trials):
        _need(isinstance(t, list) and len(t) == 4 and isinstance(t[0], str)
              and isinstance(t[1], str) and _is_int(t[2]) and t[3] in (0, 1),
              f"trials[{k}]", "[stimulus, reference, repetition, hidden]")


def _other_shape(kind: str, b: dict[str, Any]) -> None:
    if kind == "event":
        _text(b.get("kind"), "kind", 64)
        _object(b.get("details"), "details", optional=True)
    elif kind == "start":
        _object(b.get("display"), "display", optional=True)
    elif kind == "preflight":
        results = b.get("results")
        _need(isinstance(results, list) and all(isinstance(r, dict) for r in results),
              "results", "a list of JSON objects")
        _need(isinstance(b.get("skipped"), bool), "skipped", "true or false")
    elif kind == "answer":
        _text(b.get("questionnaire"), "questionnaire")
        _text(b.get("question"), "question")
        _need(_is_int(b.get("page")), "page", "an integer")
        _need(b.get("ms") is None or _is_num(b["ms"]), "ms", "a finite number or null")
    elif kind == "screening":
        _text(b.get("test"), "test")
        _text(b.get("outcome"), "outcome", 32)
        _object(b.get("result"), "result")


SHAPES = {"session": _session_shape, "rating": _rating_shape, "requeue": _requeue_shape,
          "block": _block_shape}
TIMED = ("event", "start", "preflight", "answer", "screening", "finish", "withdrawn", "block")


def check_shape(e: OutboxEntry) -> None:
    """Raise :class:`BadContent` when a body's values do not have the types the app writes."""
    if e.kind in TIMED:
        _time(e.body.get("at"), "at")
    shape = SHAPES.get(e.kind)
    if shape is not None:
        shape(e.body)
    else:
        _other_shape(e.kind, e.body)


# -- the study's design ------------------------------------------------------------------
def _known(design: StudyDesign, stimulus: str, reference: str, hidden: Any,
           where: str) -> None:
    it = design.items.get(stimulus)
    if it is None:
        raise BadContent(f"{where} names a stimulus this study does not have")
    if it.reference != reference or bool(hidden) != it.is_hidden_reference:
        raise BadContent(f"{where} gives stimulus {stimulus} another reference or "
                         "hidden-reference flag than the study")


def _check_plan(design: StudyDesign, body: dict[str, Any]) -> None:
    plan = body["plan"]
    for k, (_, stimulus, reference, _, hidden) in enumerate(plan):
        _known(design, stimulus, reference, hidden, f"plan row {k}")
    counts = Counter(row[1] for row in plan)
    n = len(plan) // max(len(design.items), 1)
    if set(counts) != set(design.items) or set(counts.values()) != {n}:
        raise BadContent("the plan does not hold every stimulus of the study equally often")
    settings = body.get("settings") or {}
    expected = 1 if design.adaptive else design.repetitions
    if n != expected and not (settings.get("simulated") is True and not design.adaptive
                              and n <= MAX_REPETITIONS):
        raise BadContent(f"the plan holds each stimulus {n} time(s); this study plans "
                         f"{expected}")
    seen: Counter[str] = Counter()
    for k, row in enumerate(plan):
        seen[row[1]] += 1
        if row[3] != seen[row[1]]:
            raise BadContent(f"plan row {k}: repetition {row[3]} where {seen[row[1]]} "
                             "was expected")


def check_design(design: StudyDesign, e: OutboxEntry) -> None:
    """Raise :class:`BadContent` when an entry (of a well-formed type) contradicts the
    study: see the module doc."""
    b = e.body
    if e.kind == "session":
        _check_plan(design, b)
    elif e.kind == "rating":
        row = b["row"]
        lo, hi = design.scale
        if not lo <= row["rating"] <= hi:
            raise BadContent(f"rating {row['rating']:g} is outside the scale {lo:g}..{hi:g}")
        _known(design, row["stimulus"], row["reference"], row["is_hidden_reference"], "row")
    elif e.kind == "block":
        if not design.adaptive:
            raise BadContent("this study does not allocate trials in blocks")
        for k, t in enumerate(b["trials"]):
            _known(design, t[0], t[1], t[3], f"trials[{k}]")


def content_problem(design: StudyDesign, e: OutboxEntry) -> str | None:
    """Why entry ``e`` is refused (one line), or None when its content fits."""
    try:
        check_shape(e)
        check_design(design, e)
    except BadContent as exc:
        return f"entry {e.seq} ({e.kind}): {exc}"
    return None
