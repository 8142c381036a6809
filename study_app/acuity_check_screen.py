"""The contrast/acuity check on the display: a credit-card calibration, then optotypes.

1. **Card**: a rectangle with the ID-1 card's aspect ratio; the participant holds a real card
   against the screen and makes the rectangle as wide (arrow keys, Shift for larger steps,
   the mouse wheel, dragging an edge, or the buttons). Its width in window pixels gives the
   geometry (:func:`.vision.acuity.card_calibration`), in the same pixels the optotypes are
   drawn in, so desktop scaling cannot distort it.
2. **Optotypes**: each drawn 1:1 at the centre of a mid-grey screen, the four directions as
   arrow keys or buttons, no feedback, a short blank between them; the order and the early
   stops come from :func:`.vision.acuity_scoring.next_trial`.

``state`` logs which trial is shown (for the end-to-end tests), never the answer.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .display import Display
from .layout import GAP, Rect, button_rows, text_screen_layout, ui_px, wrap_words
from .screens.draw import BODY, DARK, ERROR_TEXT, SCREEN_BG, TITLE, draw_box, draw_button
from .vision.acuity import (
    ID1_HEIGHT_MM,
    ID1_WIDTH_MM,
    PX_PER_MM,
    Geometry,
    background_code,
    card_calibration,
    card_rect_px,
    optotype,
)
from .vision.acuity_plan import AcuityPlan
from .vision.acuity_scoring import OptotypeAnswer, most_trials, next_trial

CARD_TEXT = ("Hold a bank card against the screen and make the rectangle exactly as wide as "
             "the card: arrow keys (hold Shift for larger steps), the mouse wheel, or drag its "
             "edge. Press Enter when it matches.")
TRIAL_TEXT = "Where is the gap? Press the arrow key pointing to it. If unsure, guess."
DIRECTIONS = (("left", "Left"), ("up", "Up"), ("right", "Right"), ("down", "Down"))
START_PX_PER_MM = 96 / 25.4  # a 96 dpi screen: where the rectangle starts
BLANK_S = 0.25
CARD_FILL = (0.86, 0.88, 0.92, 1.0)
CARD_EDGE = (0.98, 0.78, 0.22, 1.0)
ERROR = ERROR_TEXT


@dataclass
class _Card:
    """The on-screen card: its width (window pixels), kept to what real displays allow."""

    window_w: int
    widest: float
    width: float = round(START_PX_PER_MM * ID1_WIDTH_MM)
    middle: int = 0
    dragging: bool = False

    def __post_init__(self) -> None:
        self.set_width(self.width)

    def set_width(self, width: float) -> None:
        self.width = float(np.clip(width, PX_PER_MM[0] * ID1_WIDTH_MM, self.widest))

    def rect(self) -> Rect:
        cw, ch = card_rect_px(self.width)
        return Rect(self.window_w // 2 - cw // 2, self.middle - ch // 2, cw, ch)

    def near_edge(self, x: float, y: float, slack: float = 16) -> bool:
        r = self.rect()
        return abs(abs(x - self.window_w / 2) - r.w / 2) <= slack and \
            r.y - slack <= y <= r.bottom + slack


CARD_BUTTONS = [("smaller", "Smaller"), ("larger", "Larger"), ("done", "It matches")]


def card_page(window: tuple[int, int], fonts: Any) -> tuple[Any, list[str], _Card]:
    """The card screen's layout, its instruction lines and the card, which stays between
    the instructions and the buttons with a line for a refusal under it: grown past them it
    hid the text, and the buttons were drawn over it."""
    lay = text_screen_layout(window, fonts, title="Match the card", buttons=CARD_BUTTONS)
    px = ui_px(window)
    lh = fonts.line_height(px)
    lines = wrap_words(CARD_TEXT, lay.column.w, px, fonts)
    top = lay.column.y + len(lines) * lh + GAP
    bottom = min(b.rect.y for b in lay.buttons) - 2 * GAP - lh
    tallest = (bottom - top) * ID1_WIDTH_MM / ID1_HEIGHT_MM
    card = _Card(window[0], min(PX_PER_MM[1] * ID1_WIDTH_MM, window[0] - 2 * GAP, tallest))
    card.middle = (top + bottom) // 2
    return lay, lines, card


def count_text(k: int, plan: AcuityPlan, answers: list[OptotypeAnswer]) -> str:
    """The progress line under the question. The check skips what is decided, so its length
    is not known ahead: the line gives the most it can still take, which shrinks as levels
    are decided, down to the real count."""
    return f"{k} of at most {most_trials(plan, answers)}"


def optotype_room(window: tuple[int, int]) -> int:
    """The tallest optotype (in pixels) the trial screen has room for between its text and
    its buttons."""
    return max(16, round(window[1] * 0.5))


@dataclass
class AcuityCheckScreen:
    """Shows the card calibration and the optotypes on ``display``."""

    display: Display
    state: Callable[..., None]
    shot: Callable[[str], bool]
    on_close: Callable[[], None]
    on_pause: Callable[[], None] = lambda: None
    """Esc or P: the app's pause menu (continue, stop, withdraw); returns to continue."""

    def _paused(self, event: Any) -> bool:
        """Esc or P pressed: the pause menu was shown and the participant continues."""
        pg = self.display.pg
        if event.type == pg.KEYDOWN and event.key in (pg.K_ESCAPE, pg.K_p):
            self.on_pause()
            return True
        return False

    # -- 1. the card ------------------------------------------------------------------
    def calibrate(self, distance_cm: float) -> tuple[Geometry, int]:
        """(geometry, card width in window pixels) once the participant confirms a width a
        real display can have."""
        d = self.display
        pg = d.pg
        w = d.size[0]
        lay, lines, card = card_page(d.size, d.fonts)
        px = ui_px(d.size)
        lh = d.fonts.line_height(px)
        error = ""
        repeat = pg.key.get_repeat()
        pg.key.set_repeat(350, 25)
        self.state("acuity-card")
        try:
            while True:
                for event in pg.event.get():
                    if self._paused(event):
                        self.state("acuity-card")
                        continue
                    action = self._card_event(event, card, lay.buttons)
                    if action == "done":
                        error = self._confirm(card.width, distance_cm)
                        if not error:
                            return (card_calibration(card.width, distance_cm),
                                    round(card.width))
                    elif action == "changed":
                        error = ""
                r = d.renderer
                r.clear(SCREEN_BG)
                draw_box(r, lay.title, TITLE, "bold")
                for i, line in enumerate(lines):
                    r.text(line, lay.column.x, lay.column.y + i * lh, px=px, color=BODY)
                rect = card.rect()
                r.rect(*rect.as_tuple(), CARD_FILL)
                r.frame(*rect.as_tuple(), 2, CARD_EDGE)
                if error:
                    ew, _ = r.text_size(error, px - 2)
                    r.text(error, max(GAP, (w - ew) / 2), rect.bottom + GAP, px=px - 2,
                           color=ERROR)
                for b in lay.buttons:
                    draw_button(r, b, primary=b.action == "done")
                self.shot("acuity-card")
                d.flip()
        finally:
            pg.key.set_repeat(*repeat)

    def _card_event(self, event: Any, card: _Card, buttons: Any) -> str | None:
        """Apply one event to the card: ``done``, ``changed`` or None."""
        pg = self.display.pg
        step = 0.0
        if event.type == pg.QUIT:
            self.on_close()
        elif event.type == pg.KEYDOWN:
            big = 10.0 if event.mod & pg.KMOD_SHIFT else 1.0
            if event.key in (pg.K_RETURN, pg.K_KP_ENTER):
                return "done"
            if event.key in (pg.K_LEFT, pg.K_DOWN, pg.K_MINUS, pg.K_KP_MINUS):
                step = -big
            elif event.key in (pg.K_RIGHT, pg.K_UP, pg.K_PLUS, pg.K_EQUALS, pg.K_KP_PLUS):
                step = big
        elif event.type == pg.MOUSEWHEEL:
            step = float(event.y)
        elif event.type == pg.MOUSEBUTTONDOWN and event.button == 1:
            x, y = self.display.to_pixels(event.pos)
            hit = next((b.action for b in buttons if b.rect.contains_point(x, y)), None)
            if hit == "done":
                return "done"
            step = {"smaller": -1.0, "larger": 1.0}.get(hit or "", 0.0)
            card.dragging = hit is None and card.near_edge(x, y)
        elif event.type == pg.MOUSEBUTTONUP and event.button == 1:
            card.dragging = False
        elif event.type == pg.MOUSEMOTION and card.dragging:
            card.set_width(2 * abs(self.display.to_pixels(event.pos)[0] - card.window_w / 2))
            return "changed"
        if step:
            card.set_width(card.width + step)
            return "changed"
        return None

    def _confirm(self, width: float, distance_cm: float) -> str:
        """'' when the width gives a plausible geometry, else the reason to show."""
        try:
            card_calibration(width, distance_cm)
        except ValueError:
            return "That is not the width of a real card on a screen: please match it again."
        self.state("acuity-card-done", width=round(width))
        return ""

    # -- 2. the optotypes -------------------------------------------------------------
    def run(self, plan: AcuityPlan, geometry: Geometry) -> list[OptotypeAnswer]:
        """Every trial :func:`next_trial` asks for, answered; the answers in order."""
        answers: list[OptotypeAnswer] = []
        k = 0
        while (trial := next_trial(plan, answers)) is not None:
            k += 1
            img = optotype(trial.kind, trial.orientation, trial.size_arcmin, trial.contrast,
                           geometry, margin=0.25)
            self._blank()
            self.state("acuity-trial", index=k, series=trial.series, level=trial.level)
            given, ms = self._show(img, f"acuity-{trial.series}-{trial.level}",
                                   count_text(k, plan, answers))
            answers.append(OptotypeAnswer(trial, given, ms))
        return answers

    def _layout(self) -> tuple[list[str], int, list[Any]]:
        d = self.display
        px = ui_px(d.size)
        lines = wrap_words(TRIAL_TEXT, d.size[0] - 4 * GAP, px, d.fonts)
        btns = button_rows(DIRECTIONS, d.size, d.size[1] - max(GAP, round(d.size[1] * 0.04)),
                           d.fonts, px)
        return lines, px, btns

    def _background(self) -> tuple[float, float, float, float]:
        g = background_code() / 255
        return (g, g, g, 1.0)

    def _blank(self) -> None:
        """The empty grey screen between optotypes (so that one is not mistaken for a
        change of the other)."""
        d = self.display
        end = time.perf_counter() + BLANK_S
        while time.perf_counter() < end:
            for event in d.pg.event.get():
                if event.type == d.pg.QUIT:
                    self.on_close()
                elif self._paused(event):
                    end = time.perf_counter() + BLANK_S  # a whole blank before the next one
            d.renderer.clear(self._background())
            d.flip()

    def _show(self, img: np.ndarray, shot: str, count: str) -> tuple[str, float]:
        d = self.display
        pg = d.pg
        lines, px, btns = self._layout()
        lh = d.fonts.line_height(px)
        tex = d.renderer.upload_video(np.repeat(img[None, :, :, None], 3, axis=3))
        x = (d.size[0] - img.shape[1]) // 2
        y = (d.size[1] - img.shape[0]) // 2
        keys = {pg.K_LEFT: "left", pg.K_UP: "up", pg.K_RIGHT: "right", pg.K_DOWN: "down"}
        if d.pacer is not None:
            d.pacer.reset()
        start = None
        try:
            while True:
                for event in pg.event.get():
                    given = None
                    if event.type == pg.QUIT:
                        self.on_close()
                    elif self._paused(event):
                        start = None  # timed again from the next frame shown
                    elif event.type == pg.KEYDOWN and event.key in keys:
                        given = keys[event.key]
                    elif event.type == pg.MOUSEBUTTONDOWN and event.button == 1:
                        px_, py_ = d.to_pixels(event.pos)
                        given = next((b.action for b in btns
                                      if b.rect.contains_point(px_, py_)), None)
                    if given is not None and start is not None:
                        return given, round((time.perf_counter() - start) * 1000.0, 1)
                r = d.renderer
                r.clear(self._background())
                for i, line in enumerate([*lines, count]):
                    tw, _ = r.text_size(line, px)
                    r.text(line, (d.size[0] - tw) / 2, GAP + i * lh, px=px, color=DARK)
                r.draw_video(tex, 0, x, y)
                for b in btns:
                    draw_button(r, b, primary=False)
                self.shot(shot)
                d.flip()
                if start is None:
                    start = time.perf_counter()
        finally:
            tex.release()
