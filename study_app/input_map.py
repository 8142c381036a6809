"""Input events as what they mean on screen: keys of any keyboard layout, the mouse on the
slider and on buttons. Pure mapping; the trial's state machine (:mod:`.trial`) and a text
screen's state (:mod:`.screens.text_state`) decide what the meaning does."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from .keys import RATING, VIEWING, Keymap
from .layout import Button, RatingLayout
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


def button_at(buttons: Sequence[Button], x: int, y: int) -> str | None:
    """The action of the button under framebuffer pixel ``(x, y)``, or None."""
    return next((b.action for b in buttons if b.rect.contains_point(x, y)), None)


def text_screen_action(pg: Any, event: Any, keys: Keymap, buttons: Sequence[Button],
                       to_pixels: Callable[[tuple[int, int]], tuple[int, int]]) -> str | None:
    """The action a key or a left click on a button chooses on a text screen, or None (the
    wheel and the pointer's hover only move the view: the text screen reads them itself)."""
    if event.type == pg.KEYDOWN:
        return keys.action(event.key, event.scancode)
    if event.type == pg.MOUSEBUTTONDOWN and event.button == 1:
        return button_at(buttons, *to_pixels(event.pos))
    return None
