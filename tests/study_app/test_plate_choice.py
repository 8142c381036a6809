"""A colour plate's answer is chosen, shown, changeable and final only with Enter or Next:
one slipped key used to be stored as a misreading (a misread control plate makes the whole
check inconclusive). The screen runs on scripted input events and a renderer that records
what it was asked to draw."""

from __future__ import annotations

from types import SimpleNamespace

import pygame
import pytest

from study_app.colour_check_screen import ColourCheckScreen
from study_app.fonts import Fonts
from study_app.layout import text_screen_layout
from study_app.vision.isochromatic import make_plate
from study_app.vision.scoring import NO_NUMBER

from .test_panel_form_fixes import _Pg

WINDOW = (1024, 600)


class _Renderer:
    """Records the text drawn and the buttons drawn as chosen (primary)."""

    def __init__(self) -> None:
        self.texts: list[str] = []

    def upload_video(self, frames):
        return SimpleNamespace(release=lambda: None)

    def text_size(self, text: str, px: int, style: str = "regular") -> tuple[int, int]:
        return Fonts().size(text, px, style)

    def text(self, text: str, *args, **kwargs) -> None:
        self.texts.append(text)

    def clear(self, *a) -> None: ...
    def draw_video(self, *a) -> None: ...
    def rect(self, *a) -> None: ...


def _key(key: int) -> pygame.event.Event:
    return pygame.event.Event(pygame.KEYDOWN, key=key, mod=0)


def _typed(text: str) -> pygame.event.Event:
    return pygame.event.Event(pygame.TEXTINPUT, text=text)


def _click(action: str) -> pygame.event.Event:
    from study_app.colour_check_screen import NEXT

    buttons = [(str(i), str(i)) for i in range(10)] + [(NO_NUMBER, "No number"),
                                                       (NEXT, "Next")]
    lay = text_screen_layout(WINDOW, Fonts(), title="Colour vision check (1 of 1)",
                             buttons=buttons)
    r = next(b.rect for b in lay.buttons if b.action == action)
    return pygame.event.Event(pygame.MOUSEBUTTONDOWN, button=1,
                              pos=(r.x + r.w / 2, r.y + r.h / 2))


def _run(events: list[pygame.event.Event]):
    renderer = _Renderer()
    display = SimpleNamespace(pg=_Pg([[e] for e in events]), size=WINDOW, fonts=Fonts(),
                              pacer=None, renderer=renderer, flip=lambda: None,
                              to_pixels=lambda pos: pos)
    states: list[tuple] = []
    screen = ColourCheckScreen(display, lambda *a, **k: states.append((a, k)),
                               lambda name: False, lambda: None)
    [answer] = screen.run([make_plate("control", "2", seed=7, size=120)])
    return answer, renderer.texts, states


def test_a_slipped_key_is_changed_before_enter():
    answer, texts, _ = _run([_typed("8"), _typed("2"), _key(pygame.K_RETURN)])
    assert answer.given == "2" and answer.correct
    assert "Your answer: 8. Enter: next, Backspace: change." in texts
    assert "Your answer: 2. Enter: next, Backspace: change." in texts


def test_backspace_takes_the_choice_back_and_enter_alone_does_nothing():
    answer, _, states = _run([_typed("8"), _key(pygame.K_BACKSPACE), _key(pygame.K_RETURN),
                              _typed("n"), _key(pygame.K_RETURN)])
    assert answer.given == NO_NUMBER
    assert sum(1 for a, _ in states if a[0] == "colour-plate-answered") == 1


@pytest.mark.parametrize("events", [
    [_click("2"), _click("next")],
    [_click("7"), _click("2"), _click("next")],
    [_click("next"), _click("2"), _key(pygame.K_KP_ENTER)],
])
def test_the_mouse_chooses_and_next_confirms(events):
    answer, _, _ = _run(events)
    assert answer.given == "2"
