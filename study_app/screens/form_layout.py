"""Where a questionnaire page's parts go: each question's text, its option buttons or its
typing field, the line for its refusal, and the page's buttons. Pure geometry from the
window size and the font metrics, so tests can check that nothing overlaps at any size.

The questions sit in a column between the title and the buttons; a page taller than that
column scrolls (content coordinates start at 0 at the column's top).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ..layout import Button, Rect, TextBox, text_screen_layout, ui_px, wrap_words
from ..text_measure import Measure
from .form_state import FormState

PREFER_NOT_LABEL = "Prefer not to say"


@dataclass(frozen=True)
class Hit:
    """A clickable part of a question (content coordinates): an option, the "Prefer not to
    say" choice or the typing field."""

    qi: int
    kind: str  # "option", "prefer", "field"
    value: Any
    label: str
    rect: Rect


@dataclass(frozen=True)
class QuestionBox:
    """One question's parts in content coordinates."""

    qi: int
    text: TextBox
    hits: tuple[Hit, ...]
    error_y: int
    top: int
    bottom: int


@dataclass(frozen=True)
class FormLayout:
    """A questionnaire page on a window."""

    window: tuple[int, int]
    px: int
    title: TextBox
    column: Rect  # the visible part of the content, in window coordinates
    intro: TextBox | None  # content coordinates
    questions: tuple[QuestionBox, ...]
    content_height: int
    buttons: tuple[Button, ...]

    def max_offset(self) -> int:
        return max(0, self.content_height - self.column.h)

    def hit_at(self, x: float, y: float, offset: int) -> Hit | None:
        """The option or field under a window point (scrolled by ``offset``)."""
        if not self.column.contains_point(x, y):
            return None
        cx, cy = x - self.column.x, y - self.column.y + offset
        for q in self.questions:
            for h in q.hits:
                if h.rect.contains_point(cx, cy):
                    return h
        return None

    def offset_showing(self, qi: int, offset: int) -> int:
        """The scroll offset nearest ``offset`` that shows question ``qi`` whole (its top
        when it is taller than the column)."""
        q = self.questions[qi]
        if q.top < offset:
            return q.top
        if q.bottom > offset + self.column.h:
            return min(q.top, q.bottom - self.column.h)
        return offset


def number_range(q: Any) -> str:
    """ " (years, 18-99)" after a number question's text: its unit and the answers its rule
    takes, shown before a refusal has to say them."""
    if getattr(q, "type", None) != "number":
        return ""
    span = f"{q.min:g}-{q.max:g}"
    return f" ({q.unit}, {span})" if q.unit else f" ({span})"


def _scale_row(qi: int, f: Any, y: int, width: int, px: int, m: Measure) -> list[Hit]:
    """A Likert scale as one row of equal cells, each label wrapped inside its cell, with
    "Prefer not to say" as a last cell set apart (or on the row below where the row has no
    room for it): flowed left to right, "Strongly agree" wrapped under "Strongly disagree"
    and the scale no longer read as a line. Empty where a word of a label is wider than its
    cell (then the options flow as the other questions' do)."""
    points = f.options()
    prefer = f.question.offers_prefer_not_to_say
    space = round(px * 0.4)
    lh = m.line_height(px - 2)
    for beside in ((True, False) if prefer else (False,)):
        n = len(points) + beside
        apart = 3 * space if beside else 0  # the gap before "Prefer not to say"
        cell = (width - space * (n - 1) - apart) // n
        labels = [lab for _, lab in points] + ([PREFER_NOT_LABEL] if beside else [])
        wrapped = [wrap_words(lab, cell - px // 2, px - 2, m) or [lab] for lab in labels]
        if all(max(m.size(t, px - 2)[0] for t in lines) <= cell - px // 2
               for lines in wrapped) and max(map(len, wrapped)) <= 2:
            break
    else:
        return []
    bh = max(len(lines) for lines in wrapped) * lh + round(px * 0.3)
    hits = [Hit(qi, "option", value, lab, Rect(k * (cell + space), y, cell, bh))
            for k, (value, lab) in enumerate(points)]
    if beside:
        hits.append(Hit(qi, "prefer", None, PREFER_NOT_LABEL,
                        Rect(len(points) * (cell + space) + apart, y, cell, bh)))
    elif prefer:
        pw, ph = m.size(PREFER_NOT_LABEL, px - 2)
        hits.append(Hit(qi, "prefer", None, PREFER_NOT_LABEL,
                        Rect(0, y + bh + round(px * 0.25), pw + px, ph + round(px * 0.5))))
    return hits


def form_layout(window: tuple[int, int], m: Measure, *, title: str, intro: str | None,
                state: FormState, buttons: Sequence[tuple[str, str]]) -> FormLayout:
    """The page's geometry; ``intro`` (the questionnaire's, on its first page) sits above
    the questions."""
    base = text_screen_layout(window, m, title=title, buttons=buttons)
    px = ui_px(window)
    col = base.column
    width = col.w
    lh = m.line_height(px)
    gap = round(px * 0.5)
    y = 0
    intro_box = None
    if intro:
        ilines = []
        for line in wrap_words(intro, width, px - 2, m) or [intro]:
            ilines.append((line, Rect(0, y, *m.size(line, px - 2))))
            y += m.line_height(px - 2)
        intro_box = TextBox(px - 2, tuple(ilines))
        y += gap
    boxes = []
    for qi, f in enumerate(state.fields):
        top = y
        q = f.question
        optional = not q.required and "optional" not in q.text.lower()
        label = q.text + number_range(q) + (" (optional)" if optional else "")
        lines = wrap_words(label, width, px, m, "bold") or [label]
        text_lines = []
        for line in lines:
            tw, th = m.size(line, px, "bold")
            text_lines.append((line, Rect(0, y, tw, th)))
            y += lh
        y += round(px * 0.3)
        hits: list[Hit] = []
        if f.kind in ("number", "text"):
            fh = lh + round(px * 0.5)
            fw = min(width, 8 * px) if f.kind == "number" else width
            rows = 1 if f.kind == "number" else max(1, min(3, q.max_length // 60 + 1))
            hits.append(Hit(qi, "field", None, "", Rect(0, y, fw, fh * rows)))
            x_after = fw + gap
            y_field = y
            y += fh * rows + gap
            # an optional comment box left empty says it already: no button under it
            if q.offers_prefer_not_to_say and (f.kind != "text" or q.prefer_not_to_say):
                pw, ph = m.size(PREFER_NOT_LABEL, px - 2)
                bw, bh = pw + px, ph + round(px * 0.5)
                if f.kind == "number" and x_after + bw <= width:
                    hits.append(Hit(qi, "prefer", None, PREFER_NOT_LABEL,
                                    Rect(x_after, y_field, bw, bh)))
                else:
                    hits.append(Hit(qi, "prefer", None, PREFER_NOT_LABEL, Rect(0, y, bw, bh)))
                    y += bh + gap
        elif f.kind == "likert" and (scale := _scale_row(qi, f, y, width, px, m)):
            hits += scale
            y = max(h.rect.bottom for h in scale) + gap
        else:
            items = [("option", v, lab) for v, lab in f.options()]
            if q.offers_prefer_not_to_say:
                items.append(("prefer", None, PREFER_NOT_LABEL))
            x = 0
            row_h = 0
            for kind, value, lab in items:
                lines = wrap_words(lab, width - px, px - 2, m) or [lab]
                tw = max(m.size(t, px - 2)[0] for t in lines)
                bw = min(width, tw + px)
                bh = len(lines) * m.line_height(px - 2) + round(px * 0.5)
                if x and x + bw > width:
                    x, y = 0, y + row_h + round(px * 0.35)
                    row_h = 0
                hits.append(Hit(qi, kind, value, lab, Rect(x, y, bw, bh)))
                x += bw + round(px * 0.4)
                row_h = max(row_h, bh)
            y += row_h + gap
        error_y = y
        y += lh + gap  # the line a refusal is written on (kept free)
        boxes.append(QuestionBox(qi, TextBox(px, tuple(text_lines)), tuple(hits), error_y,
                                 top, y))
        y += round(px * 0.4)
    # the last question's free error line counts only when it holds a refusal: a page that
    # fits but for that empty line would otherwise scroll (and hide the key line) for nothing
    last = boxes[-1] if boxes else None
    if last is not None and not state.fields[last.qi].error:
        y = last.error_y
    return FormLayout(window, px, base.title, col, intro_box, tuple(boxes), y, base.buttons)
