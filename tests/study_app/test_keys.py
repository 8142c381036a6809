"""Keys on any keyboard layout: by the letter typed, else by the key's US position."""

from __future__ import annotations

import pygame

from study_app.keys import Keymap, key_label, keymap, letter_scancode

PAUSE = keymap(resume=["space", "enter"], quit=["q"], withdraw=["w"])
SC = letter_scancode


def test_us_layout():
    assert PAUSE.action(pygame.K_q, SC("q")) == "quit"
    assert PAUSE.action(pygame.K_SPACE, 44) == "resume"
    assert PAUSE.action(pygame.K_KP_ENTER, 88) == "resume"
    assert PAUSE.action(pygame.K_x, SC("x")) is None


def test_azerty_uses_the_letter_typed_not_the_position():
    # On AZERTY the key at the US 'A' position types 'q', and the US 'Q' position types 'a'.
    assert PAUSE.action(pygame.K_q, SC("a")) == "quit"
    assert PAUSE.action(pygame.K_a, SC("q")) is None  # typing 'a' never quits
    # 'w' sits at the US 'Z' position on AZERTY.
    assert PAUSE.action(pygame.K_w, SC("z")) == "withdraw"


def test_non_latin_layout_falls_back_to_the_position():
    cyrillic_shorthand_i = 0x439  # 'й', typed by the US 'Q' position on a Russian layout
    assert PAUSE.action(cyrillic_shorthand_i, SC("q")) == "quit"
    assert PAUSE.action(0x446, SC("w")) == "withdraw"  # 'ц'
    assert PAUSE.action(0x444, SC("a")) is None  # 'ф' at 'A': not bound here


def test_on_screen_names():
    assert PAUSE.label("resume") == "Space or Enter"
    assert PAUSE.label("quit", lambda sc: "q") == "Q"
    assert PAUSE.label("quit", lambda sc: "a") == "Q"  # AZERTY: the Q key is elsewhere
    assert PAUSE.label("quit", lambda sc: "й") == "Q / Й"
    assert key_label("q", None) == "Q"
    assert Keymap({"x": ("left", "right")}).label("x") == "← or →"
