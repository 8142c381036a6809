"""A questionnaire of the manifest's panel on the display, page by page, until it is done or
(when voluntary) skipped.

Mouse and keyboard both work: Tab / Shift+Tab (or Down / Up) move between questions, Left /
Right or the number keys choose an option, typing fills a number or text field, Backspace
deletes, Enter goes to the next page, Page Up / Page Down (or the wheel) scroll a long page.
Every valid answer is handed to ``on_answer`` as soon as it is given (a choice at once, typed
text when the participant moves on), and the app stores it in the session file at once: a
crash loses at most what is being typed, and the run resumes on the same page. What was typed
is never logged. The state machine is :mod:`.screens.form_state`, the geometry
:mod:`.screens.form_layout`.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from stimuli_manifests.panel import Questionnaire

from .display import Display
from .layout import Button
from .screens.draw import (
    ACCENT,
    BODY,
    DARK,
    ERROR_TEXT,
    MUTED,
    SCREEN_BG,
    TITLE,
    draw_box,
    draw_button,
)
from .screens.form_layout import FormLayout, form_layout
from .screens.form_state import FormState

PREFER_KEYS = {"single": "0", "likert": "0", "multiple": "0", "number": "Ctrl+P"}
"""The key that chooses "Prefer not to say" on a focused question of each kind (a number
field types digits, so there it is Ctrl+P; a text field offers no such choice by key)."""

OPTION_FILL = (0.26, 0.28, 0.31, 1.0)
FIELD_FILL = (0.08, 0.09, 0.10, 1.0)
OnAnswer = Callable[[int, str, Any], None]


def key_hint(field: Any, *, last_page: bool = False) -> str:
    """The key line under the page for the focused question: how to answer it (the "Prefer
    not to say" key where it is offered) and what Enter does on this page."""
    key = PREFER_KEYS.get(field.kind) if field.question.offers_prefer_not_to_say else None
    choose = {"number": "type a number", "text": "type your answer"}.get(
        field.kind, "1-9 or arrows: choose")
    prefer = f"   {key}: prefer not to say" if key else ""
    enter = "done" if last_page else "next page"
    return f"Tab: next question   {choose}{prefer}   Enter: {enter}   Esc: pause"


@dataclass
class FormScreen:
    """Shows questionnaires on ``display`` for the session around them (the app)."""

    display: Display
    state: Callable[..., None]
    """Logs a screen change (``state(name, **details)``; never an answer)."""
    shot: Callable[[str], bool]
    on_close: Callable[[], None]
    """The window's close button: the app confirms (and stops the run by raising) or
    returns, and the page goes on."""
    on_pause: Callable[[], None] = lambda: None
    """Esc: the app's pause menu (continue, stop, withdraw); returns to continue (P types a
    letter here, so only Esc)."""

    def run(self, qn: Questionnaire, *, answered: dict[str, Any], start_page: int,
            on_answer: OnAnswer) -> str:
        """Show ``qn`` from ``start_page``; returns ``done`` or ``skipped``."""
        pg = self.display.pg
        answered = dict(answered)
        page = max(0, min(start_page, len(qn.pages) - 1))
        pg.key.start_text_input()
        try:
            while True:
                outcome = self._page(qn, page, answered, on_answer)
                if outcome == "skip":
                    self.state("questionnaire-skipped", id=qn.id)
                    return "skipped"
                page += -1 if outcome == "back" else 1
                if page >= len(qn.pages):
                    self.state("questionnaire-done", id=qn.id)
                    return "done"
        finally:
            pg.key.stop_text_input()

    def _buttons(self, qn: Questionnaire, page: int) -> list[tuple[str, str]]:
        items = []
        if page > 0:
            items.append(("back", "Back (Alt+\u2190)"))
        if qn.voluntary:
            items.append(("skip", "Skip these questions (Alt+S)"))
        items.append(("next", "Next" if page < len(qn.pages) - 1 else "Done"))
        return items

    def _page(self, qn: Questionnaire, page: int, answered: dict[str, Any],
              on_answer: OnAnswer) -> str:
        d = self.display
        pg = d.pg
        p = qn.pages[page]
        fs = FormState.for_page(list(p.questions), answered)
        title = f"{qn.title} ({page + 1} of {len(qn.pages)})" if len(qn.pages) > 1 \
            else qn.title
        intro = qn.intro if page == 0 else None
        offset = 0
        shown_focus = fs.focus  # the question last brought into view (a page opens at its top)
        name = f"questionnaire-{qn.id}-{page + 1}"
        self.state("questionnaire", id=qn.id, page=page + 1, questions=len(fs.fields))
        if d.pacer is not None:
            d.pacer.reset()

        def store(qid: str, value: Any) -> None:
            answered[qid] = value
            on_answer(page, qid, value)
            self.state("answered", id=qn.id, question=qid)

        def commit(qi: int) -> None:
            changed, value = fs.to_store(qi)
            if changed:  # a new answer, or None for one taken back
                store(fs.fields[qi].question.id, value)

        while True:
            lay = form_layout(d.size, d.fonts, title=title, intro=intro, state=fs,
                              buttons=self._buttons(qn, page))
            for event in pg.event.get():
                if event.type == pg.QUIT:
                    self.on_close()
                    self.state("questionnaire", id=qn.id, page=page + 1)
                    continue
                if event.type == pg.KEYDOWN and event.key == pg.K_ESCAPE:
                    commit(fs.focus)  # what the focused field holds is kept, as on Tab
                    self.on_pause()
                    self.state("questionnaire", id=qn.id, page=page + 1)
                    continue
                action = self._event(event, fs, lay, offset)
                if action is None:
                    continue
                if action.startswith("commit:"):
                    qi = int(action.split(":")[1])
                    commit(qi)
                    if fs.focus != qi:
                        fs.left(qi)
                    continue
                if action == "scroll-up":
                    offset = max(0, offset - lay.column.h // 2)
                    continue
                if action == "scroll-down":
                    offset = min(lay.max_offset(), offset + lay.column.h // 2)
                    continue
                if action == "wheel":
                    offset = min(lay.max_offset(), max(0, offset - 40 * int(event.y)))
                    continue
                if action == "skip":  # what this page holds is taken back, not stored
                    for qid in fs.take_back():
                        store(qid, None)
                    return "skip"
                for qi in range(len(fs.fields)):
                    commit(qi)
                if action == "back":
                    return "back"
                if action == "next":
                    if fs.validate_page():
                        return "next"
                    self.state("questionnaire-refused", id=qn.id, page=page + 1,
                               question=fs.fields[fs.focus].question.id)
                    offset = lay.offset_showing(fs.focus, offset)
            lay = form_layout(d.size, d.fonts, title=title, intro=intro, state=fs,
                              buttons=self._buttons(qn, page))
            if fs.focus != shown_focus:  # brought into view when it moves, not on each
                offset = lay.offset_showing(fs.focus, offset)  # scroll (it pulled back)
                shown_focus = fs.focus
            offset = max(0, min(offset, lay.max_offset()))
            draw_form(d.renderer, lay, fs, offset)
            self.shot(name)
            d.flip()

    def _event(self, event: Any, fs: FormState, lay: FormLayout, offset: int) -> str | None:
        """One input event applied to the page; returns what the loop must do next
        (``commit:<qi>``, a scroll, or a button's action), or None."""
        pg = self.display.pg
        focus = fs.focus
        kind = fs.fields[focus].kind
        if event.type == pg.MOUSEWHEEL:
            return "wheel"
        if event.type == pg.TEXTINPUT:
            if kind in ("number", "text"):
                fs.type(focus, event.text)
            elif event.text == PREFER_KEYS.get(kind):
                fs.toggle_prefer_not(focus)
                return f"commit:{focus}"
            elif event.text.isdigit() and kind in ("single", "likert", "multiple"):
                options = fs.fields[focus].options()
                k = int(event.text) - 1
                if 0 <= k < len(options):
                    fs.choose(focus, options[k][0])
                    return f"commit:{focus}"
            return None
        if event.type == pg.MOUSEBUTTONDOWN and event.button == 1:
            x, y = self.display.to_pixels(event.pos)
            button = _button_at(lay.buttons, x, y)
            if button is not None:
                return button
            hit = lay.hit_at(x, y, offset)
            if hit is None:
                return None
            before = fs.focus
            if hit.kind == "option":
                fs.choose(hit.qi, hit.value)
            elif hit.kind == "prefer":
                fs.toggle_prefer_not(hit.qi)
            else:
                fs.focus = hit.qi
            return f"commit:{before}" if hit.kind == "field" else f"commit:{hit.qi}"
        if event.type != pg.KEYDOWN:
            return None
        key, shift = event.key, bool(event.mod & pg.KMOD_SHIFT)
        if event.mod & pg.KMOD_ALT and key in (pg.K_LEFT, pg.K_s):
            # a modifier: letters and arrows alone type or choose in the fields
            action = "back" if key == pg.K_LEFT else "skip"
            return action if any(b.action == action for b in lay.buttons) else None
        if key == pg.K_p and event.mod & pg.KMOD_CTRL and kind != "text":
            fs.toggle_prefer_not(focus)
            return f"commit:{focus}"
        if key == pg.K_TAB:
            fs.move_focus(-1 if shift else 1)
            return f"commit:{focus}"
        if key in (pg.K_DOWN, pg.K_UP) and kind != "text":
            fs.move_focus(1 if key == pg.K_DOWN else -1)
            return f"commit:{focus}"
        if key in (pg.K_LEFT, pg.K_RIGHT) and kind in ("single", "likert"):
            fs.step(focus, 1 if key == pg.K_RIGHT else -1)
            return f"commit:{focus}"
        if key == pg.K_BACKSPACE:
            fs.backspace(focus)
            return None
        if key in (pg.K_RETURN, pg.K_KP_ENTER):
            return "next"
        if key == pg.K_PAGEUP:
            return "scroll-up"
        if key == pg.K_PAGEDOWN:
            return "scroll-down"
        return None


def _button_at(buttons: tuple[Button, ...], x: float, y: float) -> str | None:
    for b in buttons:
        if b.rect.contains_point(x, y):
            return b.action
    return None


def draw_form(r: Any, lay: FormLayout, fs: FormState, offset: int) -> None:
    """Paint a page: only parts wholly inside the visible column are drawn."""
    r.clear(SCREEN_BG)
    draw_box(r, lay.title, TITLE, "bold")
    col = lay.column
    top, bottom = offset, offset + col.h

    def visible(rect: Any) -> bool:
        return rect.y >= top and rect.y + rect.h <= bottom

    def at(rect: Any) -> tuple[int, int]:
        return col.x + rect.x, col.y + rect.y - offset

    if lay.intro is not None:
        for text, rect in lay.intro.lines:
            if visible(rect):
                r.text(text, *at(rect), px=lay.intro.px, color=MUTED)
    for q in lay.questions:
        f = fs.fields[q.qi]
        focused = q.qi == fs.focus
        if focused and q.top >= top:
            x, y = at(q.text.rects[0])
            r.rect(x - 14, y, 5, min(q.bottom, bottom) - q.text.rects[0].y, ACCENT)
        for text, rect in q.text.lines:
            if visible(rect):
                r.text(text, *at(rect), px=q.text.px, color=TITLE if focused else BODY,
                       style="bold")
        for h in q.hits:
            if not visible(h.rect):
                continue
            x, y = at(h.rect)
            px = lay.px - 2
            if h.kind == "field":
                r.rect(x, y, h.rect.w, h.rect.h, FIELD_FILL)
                r.frame(x, y, h.rect.w, h.rect.h, 2, ACCENT if focused else MUTED)
                _field_text(r, f.text + ("|" if focused else ""), x, y, h.rect, px)
                continue
            chosen = (f.prefer_not if h.kind == "prefer" else not f.prefer_not and (
                h.value in (f.choice or []) if f.kind == "multiple" else h.value == f.choice))
            r.rect(x, y, h.rect.w, h.rect.h, ACCENT if chosen else OPTION_FILL)
            lines = _wrap(r, h.label, h.rect.w - lay.px // 2, px)
            ty = y + (h.rect.h - len(lines) * r.text_size("Ag", px)[1]) / 2
            for line in lines:
                tw, th = r.text_size(line, px)
                r.text(line, x + (h.rect.w - tw) / 2, ty, px=px,
                       color=DARK if chosen else (1.0, 1.0, 1.0, 1.0))
                ty += th
        if f.error and top <= q.error_y <= bottom - lay.px:
            r.text(f.error, col.x, col.y + q.error_y - offset, px=lay.px - 2, color=ERROR_TEXT,
                   style="bold")
    hint_y = col.y + col.h + 4
    last = any(b.action == "next" and b.text.startswith("Done") for b in lay.buttons)
    keys = key_hint(fs.fields[fs.focus], last_page=last)
    hint = keys if offset == 0 and offset >= lay.max_offset() else (
        "more below (Page Down)" if offset < lay.max_offset() else "more above (Page Up)")
    tw, _ = r.text_size(hint, lay.px - 4)
    r.text(hint, lay.window[0] / 2 - tw / 2, hint_y, px=lay.px - 4,
           color=MUTED if hint == keys else ACCENT)
    for b in lay.buttons:
        draw_button(r, b, primary=b.action == "next")


def _wrap(r: Any, text: str, width: int, px: int) -> list[str]:
    lines: list[str] = []
    for word in text.split():
        if lines and r.text_size(f"{lines[-1]} {word}", px)[0] <= width:
            lines[-1] += f" {word}"
        else:
            lines.append(word)
    return lines or [text]


def wrap_typed(text: str, width: float, measure: Callable[[str], float]) -> list[str]:
    """Typed text in lines no wider than ``width``, broken between words (a word wider than
    a line is broken where it must); spaces are kept as typed, so the caret stays where the
    participant expects it. It broke mid-word ("com|ment")."""
    lines = [""]
    for word in re.findall(r"\S+\s*|\s+", text):
        if measure(lines[-1] + word.rstrip()) <= width or not lines[-1]:
            lines[-1] += word
        else:
            lines.append(word)
        while measure(lines[-1].rstrip()) > width and len(lines[-1]) > 1:  # one long word
            cut = len(lines[-1]) - 1
            while cut > 1 and measure(lines[-1][:cut]) > width:
                cut -= 1
            lines[-1:] = [lines[-1][:cut], lines[-1][cut:]]
    return lines


def _field_text(r: Any, text: str, x: int, y: int, rect: Any, px: int) -> None:
    """Typed text inside its field: wrapped into the field's rows, the end kept visible."""
    pad = 8
    width = rect.w - 2 * pad
    lh = r.text_size("Ag", px)[1]
    rows = max(1, (rect.h - pad) // lh)
    lines = wrap_typed(text, width, lambda t: r.text_size(t, px)[0])
    for k, line in enumerate(lines[-rows:]):
        r.text(line, x + pad, y + pad // 2 + k * lh, px=px, color=BODY)
