"""How a participant's session was run, from the settings the player stored with it: the
practice trials shown first (not rated) and how often a break was offered."""

from __future__ import annotations

from typing import Any


def _setting(recs: list, key: str) -> float:
    """The first session's value of ``key`` (NaN when no session stored it)."""
    for r in recs:
        value = (r.info.settings or {}).get(key)
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
    return float("nan")


def session_protocol(recs: list) -> dict[str, Any]:
    """``practice_trials`` and ``break_every`` (0: no breaks) of the participant's first
    session."""
    return {"practice_trials": _setting(recs, "practice_trials"),
            "break_every": _setting(recs, "break_every")}
