"""Input events as trial commands: keys of any keyboard layout, the mouse on the slider and
the buttons. Pure mapping; the trial's state machine (:mod:`.trial`) decides what they do."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .keys import RATING, VIEWING
from .layout import RatingLayout
from .trial import RATE, VIEW, Command

STEP_ACTIONS = ("left", "right", "up_coarse", "down_coarse")


def event_command(pg: Any, event: Any, phase: str, rlay: RatingLayout,
                  to_pixels: Callable[[tuple[int, int]], tuple[int, int]]) -> Command | None:
    """An input event as a trial command, or None when the event means nothing now.
    ``to_pixels`` turns window coordinates into framebuffer pixels (display scaling)."""
    if event.type == pg.KEYDOWN:
        keys = VIEWING if phase == VIEW else RATING
        action = keys.action(event.key, event.scancode)
        if action is None:
            return None
        if action in STEP_ACTIONS:
            coarse = action.endswith("coarse") or bool(
                event.mod & (pg.KMOD_SHIFT | pg.KMOD_CTRL))
            direction = -1 if action in ("left", "down_coarse") else 1
            return Command("step", direction=direction, coarse=coarse)
        return Command(action)
    if phase != RATE:
        return None
    if event.type == pg.MOUSEBUTTONDOWN and event.button == 1:
        x, y = to_pixels(event.pos)
        for b in rlay.buttons:
            if b.rect.contains_point(x, y):
                return Command(b.action)
        return Command("press", x=x, y=y)  # the slider takes it when it hits the track
    if event.type == pg.MOUSEMOTION:
        x, _ = to_pixels(event.pos)
        return Command("drag", x=x)
    if event.type == pg.MOUSEBUTTONUP and event.button == 1:
        return Command("release")
    return None
