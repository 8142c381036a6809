"""When the player offers a break between rated trials (pure)."""

from __future__ import annotations

LAST_STRETCH = 4
"""No break when fewer than ``every // LAST_STRETCH`` trials are left: a break a few trials
before the end only delays the end (with breaks every 40, none once fewer than 10 are left)."""


def break_due(since_break: int, every: int, left: int) -> bool:
    """A break after ``since_break`` trials in a row, every ``every`` trials (0: never), with
    ``left`` trials still to rate."""
    if every <= 0 or since_break < every or left <= 0:
        return False
    return left >= max(1, every // LAST_STRETCH)
