"""The colour-vision check on the display: one generated plate after another (see
:mod:`.vision.isochromatic`), the participant types or clicks the number seen, or "No number".
No feedback is given; the answers and their times are scored by :mod:`.vision.scoring` and
stored by the app. The plate is drawn 1:1 like a video, centred between the question and the
answer buttons."""

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

QUESTION = "Which number do you see in the circle? Type it, or press N if you see none."


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
        buttons = [(str(i), str(i)) for i in range(10)] + [(NO_NUMBER, "No number")]
        lay = text_screen_layout(d.size, d.fonts, title=f"Colour vision check ({k + 1} of {n})",
                                 buttons=buttons)
        px = ui_px(d.size)
        btns = list(lay.buttons)
        size = plate.image.shape[0]
        top = lay.column.y + 2 * d.fonts.line_height(px)
        bottom = min(b.rect.y for b in btns) - GAP
        rect = Rect((d.size[0] - size) // 2, top + max(0, (bottom - top - size) // 2), size,
                    size)
        tex = d.renderer.upload_video(plate.image[None])
        start = time.perf_counter()
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
                        start = time.perf_counter()  # the pause is no reading time
                        continue
                    if given is not None:
                        ms = (time.perf_counter() - start) * 1000.0
                        self.state("colour-plate-answered", index=k + 1)
                        return PlateAnswer(plate.kind, plate.answer, given, round(ms, 1))
                r = d.renderer
                r.clear(SCREEN_BG)
                draw_box(r, lay.title, TITLE, "bold")
                tw, _ = r.text_size(QUESTION, px - 2)
                r.text(QUESTION, (d.size[0] - tw) / 2, lay.column.y, px=px - 2, color=BODY)
                r.draw_video(tex, 0, rect.x, rect.y)
                for b in btns:
                    draw_button(r, b, primary=False)
                self.shot(f"colour-plate-{plate.kind}")
                d.flip()
        finally:
            tex.release()

    def _answer(self, event: Any, btns: list) -> str | None:
        pg = self.display.pg
        if event.type == pg.QUIT:
            return "close"
        if event.type == pg.KEYDOWN and event.key in (pg.K_ESCAPE, pg.K_p):
            return "pause"
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
