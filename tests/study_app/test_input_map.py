"""Input events as what they mean: trial commands and text-screen actions (no display)."""

from __future__ import annotations

from types import SimpleNamespace

import pygame

from study_app.input_map import button_at, event_command, text_screen_action
from study_app.keys import SCROLL, keymap, letter_scancode, merge
from study_app.layout import Button, Rect
from study_app.trial import RATE, VIEW

BUTTONS = (Button("back", "Back", Rect(10, 10, 100, 40), 20),
           Button("submit", "Submit", Rect(200, 10, 100, 40), 20))
RLAY = SimpleNamespace(buttons=BUTTONS)


def halve(pos: tuple[int, int]) -> tuple[int, int]:
    """Window coordinates to pixels on a display scaled by two."""
    return pos[0] * 2, pos[1] * 2


def key(k: int, scancode: int = 0, mod: int = 0) -> SimpleNamespace:
    return SimpleNamespace(type=pygame.KEYDOWN, key=k, scancode=scancode, mod=mod)


def click(pos: tuple[int, int], button: int = 1, kind: int = pygame.MOUSEBUTTONDOWN
          ) -> SimpleNamespace:
    return SimpleNamespace(type=kind, pos=pos, button=button)


def test_viewing_keys_become_trial_commands():
    assert event_command(pygame, key(pygame.K_SPACE), VIEW, RLAY, halve).name == "switch"
    assert event_command(pygame, key(pygame.K_RETURN), VIEW, RLAY, halve).name == "rate"
    assert event_command(pygame, key(pygame.K_LEFT), VIEW, RLAY, halve) is None


def test_rating_steps_are_fine_or_coarse():
    fine = event_command(pygame, key(pygame.K_LEFT), RATE, RLAY, halve)
    assert (fine.name, fine.direction, fine.coarse) == ("step", -1, False)
    shifted = event_command(pygame, key(pygame.K_RIGHT, mod=pygame.KMOD_LSHIFT), RATE, RLAY,
                            halve)
    assert (shifted.direction, shifted.coarse) == (1, True)
    page = event_command(pygame, key(pygame.K_PAGEDOWN), RATE, RLAY, halve)
    assert (page.direction, page.coarse) == (-1, True)


def test_mouse_on_the_rating_screen_in_pixels():
    assert event_command(pygame, click((120, 15)), RATE, RLAY, halve).name == "submit"
    press = event_command(pygame, click((300, 200)), RATE, RLAY, halve)
    assert (press.name, press.x, press.y) == ("press", 600, 400)
    drag = event_command(pygame, SimpleNamespace(type=pygame.MOUSEMOTION, pos=(7, 9)), RATE,
                         RLAY, halve)
    assert (drag.name, drag.x) == ("drag", 14)
    up = click((1, 1), kind=pygame.MOUSEBUTTONUP)
    assert event_command(pygame, up, RATE, RLAY, halve).name == "release"
    assert event_command(pygame, click((120, 15), button=3), RATE, RLAY, halve) is None
    assert event_command(pygame, click((120, 15)), VIEW, RLAY, halve) is None


def test_button_at():
    assert button_at(BUTTONS, 10, 10) == "back"
    assert button_at(BUTTONS, 250, 30) == "submit"
    assert button_at(BUTTONS, 150, 30) is None


def test_text_screen_actions_from_keys_and_left_clicks_only():
    keys = merge(keymap(accept=["a"], decline=["esc"]), SCROLL)
    act = text_screen_action
    assert act(pygame, key(pygame.K_a, letter_scancode("a")), keys, BUTTONS, halve) == "accept"
    assert act(pygame, key(pygame.K_PAGEDOWN), keys, BUTTONS, halve) == "page_down"
    assert act(pygame, key(pygame.K_x, letter_scancode("x")), keys, BUTTONS, halve) is None
    assert act(pygame, click((110, 10)), keys, BUTTONS, halve) == "submit"
    assert act(pygame, click((110, 10), button=3), keys, BUTTONS, halve) is None
    assert act(pygame, click((70, 10)), keys, BUTTONS, halve) is None
    wheel = SimpleNamespace(type=pygame.MOUSEWHEEL, y=-1)
    assert act(pygame, wheel, keys, BUTTONS, halve) is None
