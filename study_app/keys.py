"""Keys on any keyboard layout: letters by what the key types, or by where the key sits.

A binding names a letter ("A" to accept). On a layout that has that letter (QWERTY, AZERTY,
QWERTZ, Dvorak ...) the key that types it works, wherever it is. On a layout without Latin
letters (Cyrillic, Greek, Hebrew ...) the key types something else, so the key at the letter's
US position (its scancode) works instead, and the screen names both ("A / Ф"). Space, Enter,
Esc and the arrows are the same everywhere. Every action of the rating and text screens also
has an on-screen button (the viewing screen is keyboard-only).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
import pygame

SPECIAL = {
    "space": (pygame.K_SPACE,),
    "enter": (pygame.K_RETURN, pygame.K_KP_ENTER),
    "esc": (pygame.K_ESCAPE,),
    "left": (pygame.K_LEFT,),
    "right": (pygame.K_RIGHT,),
    "up": (pygame.K_UP,),
    "down": (pygame.K_DOWN,),
    "pageup": (pygame.K_PAGEUP,),
    "pagedown": (pygame.K_PAGEDOWN,),
    "home": (pygame.K_HOME,),
    "end": (pygame.K_END,),
}
SPECIAL_NAMES = {"space": "Space", "enter": "Enter", "esc": "Esc", "left": "←", "right": "→",
                 "up": "↑", "down": "↓", "pageup": "Page Up", "pagedown": "Page Down",
                 "home": "Home", "end": "End"}


def letter_scancode(letter: str) -> int:
    """USB HID scancode of a letter's key on a US keyboard (A=4 ... Z=29)."""
    c = letter.lower()
    if len(c) != 1 or not "a" <= c <= "z":
        raise ValueError(f"not a letter: {letter!r}")
    return 4 + ord(c) - ord("a")


def _is_latin_letter_key(key: int) -> bool:
    return ord("a") <= key <= ord("z")


@dataclass(frozen=True)
class Keymap:
    """Actions bound to keys: each value is a tuple of ``"space"``-style names or letters."""

    bindings: Mapping[str, tuple[str, ...]]

    def action(self, key: int, scancode: int) -> str | None:
        """The action of a key press (``key``: layout keycode, ``scancode``: position)."""
        for action, names in self.bindings.items():
            for name in names:
                if name in SPECIAL and key in SPECIAL[name]:
                    return action
                if len(name) == 1 and _is_latin_letter_key(key) and key == ord(name.lower()):
                    return action
        if _is_latin_letter_key(key):
            return None
        for action, names in self.bindings.items():
            for name in names:
                if len(name) == 1 and scancode == letter_scancode(name):
                    return action
        return None

    def label(self, action: str, layout_name: Callable[[int], str | None] | None = None
              ) -> str:
        """How to name the keys of ``action`` on screen ("Space", "A", "A / Ф")."""
        parts = []
        for name in self.bindings.get(action, ()):
            if name in SPECIAL_NAMES:
                parts.append(SPECIAL_NAMES[name])
            else:
                here = layout_name(letter_scancode(name)) if layout_name else None
                parts.append(key_label(name, here))
        return " or ".join(parts)


def key_label(letter: str, layout_name: str | None) -> str:
    """On-screen name of a letter binding, given what the layout puts at its US position."""
    up = letter.upper()
    if not layout_name or len(layout_name) != 1:
        return up
    if "a" <= layout_name.lower() <= "z":
        return up  # a Latin layout: the key that types this letter works
    return f"{up} / {layout_name.upper()}"


def merge(*maps: Keymap) -> Keymap:
    out: dict[str, tuple[str, ...]] = {}
    for m in maps:
        out.update(m.bindings)
    return Keymap(out)


def keymap(**bindings: Iterable[str]) -> Keymap:
    return Keymap({a: tuple(v) for a, v in bindings.items()})


# The bindings of each screen (one place, shown on screen and in the README).
VIEWING = keymap(switch=["space"], rate=["enter"], pause=["p", "esc"])
RATING = keymap(submit=["enter"], back=["space"], pause=["p", "esc"], left=["left"],
                right=["right"], up_coarse=["pageup"], down_coarse=["pagedown"])
SCROLL = keymap(scroll_up=["up"], scroll_down=["down"], page_up=["pageup"],
                page_down=["pagedown"], home=["home"], end=["end"])
