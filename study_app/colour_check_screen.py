"""The colour-vision check on the display: one generated plate after another (see
:mod:`.vision.isochromatic`), the participant types or clicks the number seen, or "No number".
The choice shows under the question and is confirmed with Enter or Next (a slipped key can be
changed). No feedback is given; the answers and their times are scored by
:mod:`.vision.scoring` and stored by the app. The plate is drawn 1:1 like a video, centred
between the question and the answer buttons."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .display import Display
from .layout import GAP, Rect, text_screen_layout, ui_px
from .screens.draw import BODY, SCREEN_BG, TITLE, draw_box, draw_button
from .vision.isochromatic import Plate
from .vision.scoring import NO_NUMBER, PlateAnswer

QUESTION = ("Which number do you see in the circle? Type it (N if you see none), then press "
            "Enter.")
NEXT = "next"


@dataclass
class PlateChoice:
    """One plate's answer as the participant gives it: a digit or "No number", changed at
    will (another key, Backspace), final with Enter or Next, so that a slipped key is not
    stored as a misreading. The time is the reading time: from the plate to the choice
    that was confirmed."""

    chosen: str | None = None
    ms: float | None = None

    def choose(self, value: str, ms: float) -> None:
        if value != self.chosen:
            self.chosen, self.ms = value, ms

    def clear(self) -> None:
        self.chosen = self.ms = None

    def shown(self) -> str:
        """The line under the question."""
        if self.chosen is None:
            return ""
        said = "no number" if self.chosen == NO_NUMBER else self.chosen
        return f"Your answer: {said}. Enter: next, Backspace: change."


def plate_size(window: tuple[int, int]) -> int:
    """The plates' size for a window: large, leaving room for the texts and buttons."""
    return max(160, min(400, round(window[1] * 0.48)))


@dataclass
class ColourCheckScreen:
    """Shows the plates on ``display``; ``state`` logs which plate is shown, never what the
    participant answered."""

    display: Display
    state: Callable[..., None]
    shot: Callable[[str], bool]
    on_close: Callable[[], None]
    on_pause: Callable[[], None] = lambda: None
    """Esc or P: the app's pause menu (continue, stop, withdraw); returns to continue."""

    def run(self, plates: list[Plate]) -> list[PlateAnswer]:
        return [self._plate(k, plate, len(plates)) for k, plate in enumerate(plates)]

    def _plate(self, k: int, plate: Plate, n: int) -> PlateAnswer:
        d = self.display
        pg = d.pg
        buttons = [(str(i), str(i)) for i in range(10)] + [(NO_NUMBER, "No number"),
                                                           (NEXT, "Next")]
        lay = text_screen_layout(d.size, d.fonts, title=f"Colour vision check ({k + 1} of {n})",
                                 buttons=buttons)
        px = ui_px(d.size)
        btns = list(lay.buttons)
        size = plate.image.shape[0]
        top = lay.column.y + 3 * d.fonts.line_height(px)
        bottom = min(b.rect.y for b in btns) - GAP
        rect = Rect((d.size[0] - size) // 2, top + max(0, (bottom - top - size) // 2), size,
                    size)
        tex = d.renderer.upload_video(plate.image[None])
        start = time.perf_counter()
        choice = PlateChoice()
        self.state("colour-plate", index=k + 1, of=n, kind=plate.kind)
        if d.pacer is not None:
            d.pacer.reset()
        try:
            while True:
                for event in pg.event.get():
                    given = self._answer(event, btns)
                    if given == "close":
                        self.on_close()
                        continue
                    if given == "pause":
                        self.on_pause()
                        self.state("colour-plate", index=k + 1, of=n, kind=plate.kind)
                        # the pause is no reading time (a choice made before it keeps its time)
                        start = time.perf_counter() - (choice.ms or 0.0) / 1000.0
                        continue
                    if given == "clear":
                        choice.clear()
                    elif given == NEXT:
                        if choice.chosen is not None:
                            self.state("colour-plate-answered", index=k + 1)
                            return PlateAnswer(plate.kind, plate.answer, choice.chosen,
                                               round(choice.ms or 0.0, 1))
                    elif given is not None:
                        choice.choose(given, (time.perf_counter() - start) * 1000.0)
                r = d.renderer
                r.clear(SCREEN_BG)
                draw_box(r, lay.title, TITLE, "bold")
                lh = d.fonts.line_height(px)
                for i, line in enumerate((QUESTION, choice.shown())):
                    tw, _ = r.text_size(line, px - 2)
                    r.text(line, (d.size[0] - tw) / 2, lay.column.y + i * lh, px=px - 2,
                           color=BODY)
                r.draw_video(tex, 0, rect.x, rect.y)
                for b in btns:
                    draw_button(r, b, primary=b.action == choice.chosen,
                                enabled=b.action != NEXT or choice.chosen is not None)
                self.shot(f"colour-plate-{plate.kind}" + ("-chosen" if choice.chosen else ""))
                d.flip()
        finally:
            tex.release()

    def _answer(self, event: Any, btns: list) -> str | None:
        pg = self.display.pg
        if event.type == pg.QUIT:
            return "close"
        if event.type == pg.KEYDOWN and event.key in (pg.K_ESCAPE, pg.K_p):
            return "pause"
        if event.type == pg.KEYDOWN and event.key in (pg.K_RETURN, pg.K_KP_ENTER):
            return NEXT
        if event.type == pg.KEYDOWN and event.key in (pg.K_BACKSPACE, pg.K_DELETE):
            return "clear"
        if event.type == pg.TEXTINPUT:
            if event.text.isdigit() and len(event.text) == 1:
                return event.text
            if event.text.lower() == "n":
                return NO_NUMBER
        if event.type == pg.MOUSEBUTTONDOWN and event.button == 1:
            x, y = self.display.to_pixels(event.pos)
            for b in btns:
                if b.rect.contains_point(x, y):
                    return b.action
        return None
