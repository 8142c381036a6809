"""Where everything goes on the participant's screens, as rectangles (pure geometry).

The drawing code draws exactly these rectangles, and the tests check them: no text rectangle
of the viewing screen ever intersects the video rectangle, nothing leaves the window, and the
rating screen's parts do not overlap, at every window size the pre-flight accepts. Text sizes
come from a ``measure`` object (the shipped font's real metrics in the app and the tests).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from .text_measure import Measure

GAP = 12  # pixels between the video and text, and between text and the window's edge
BADGE_PAD = (10, 5)  # horizontal, vertical padding inside a label badge
MIN_PX = 14


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle in window pixels, origin top left."""

    x: int
    y: int
    w: int
    h: int

    @property
    def right(self) -> int:
        return self.x + self.w

    @property
    def bottom(self) -> int:
        return self.y + self.h

    def intersects(self, other: Rect) -> bool:
        return (self.x < other.right and other.x < self.right
                and self.y < other.bottom and other.y < self.bottom)

    def inside(self, width: int, height: int) -> bool:
        return self.x >= 0 and self.y >= 0 and self.right <= width and self.bottom <= height

    def contains_point(self, x: float, y: float) -> bool:
        return self.x <= x <= self.right and self.y <= y <= self.bottom

    def as_tuple(self) -> tuple[int, int, int, int]:
        return self.x, self.y, self.w, self.h


def ui_px(window: tuple[int, int]) -> int:
    """Body text size for a window: readable at 800x600, not shouting at 4K (18 up to
    1280x720, where 20 pushed the practice's pause and withdraw keys below the fold)."""
    h = window[1]
    if h < 760:
        return 18
    if h < 950:
        return 20
    if h < 1300:
        return 24
    return 28


def video_rect(window: tuple[int, int], video: tuple[int, int]) -> Rect:
    """The video centred at 1:1 pixels (the renderer draws it exactly here)."""
    return Rect((window[0] - video[0]) // 2, (window[1] - video[1]) // 2, video[0], video[1])


# -- the viewing screen -------------------------------------------------------------------
@dataclass(frozen=True)
class TextBox:
    """Lines of text at one size, each line's rectangle given."""

    px: int
    lines: tuple[tuple[str, Rect], ...]

    @property
    def rects(self) -> list[Rect]:
        return [r for _, r in self.lines]


@dataclass(frozen=True)
class ViewingLayout:
    """The viewing screen: the video, its label badge, progress and the key hints."""

    window: tuple[int, int]
    video: Rect
    label: Rect | None
    label_px: int
    progress: TextBox | None
    hints: TextBox | None
    notice: TextBox | None

    def text_rects(self) -> list[Rect]:
        out = [self.label] if self.label else []
        for box in (self.progress, self.hints, self.notice):
            if box is not None:
                out += box.rects
        return out


def _margins(window: tuple[int, int], video: Rect) -> dict[str, Rect]:
    w, h = window
    return {
        "left": Rect(0, 0, video.x, h),
        "right": Rect(video.right, 0, w - video.right, h),
        "top": Rect(0, 0, w, video.y),
        "bottom": Rect(0, video.bottom, w, h - video.bottom),
    }


def _stack(lines: Sequence[str], px: int, m: Measure, x: int, y: int,
           align: str = "left", width: int = 0) -> TextBox:
    out = []
    step = round(m.line_height(px) * 1.2)
    for i, text in enumerate(lines):
        tw, th = m.size(text, px)
        tx = x if align == "left" else x + width - tw if align == "right" else x + (width - tw) // 2
        out.append((text, Rect(tx, y + i * step, tw, th)))
    return TextBox(px, tuple(out))


def _box_extent(lines: Sequence[str], px: int, m: Measure) -> tuple[int, int]:
    step = round(m.line_height(px) * 1.2)
    w = max((m.size(t, px)[0] for t in lines), default=0)
    h = (len(lines) - 1) * step + m.size("Ag", px)[1] if lines else 0
    return w, h


def _free(r: Rect, window: tuple[int, int], taken: Sequence[Rect]) -> bool:
    return r.inside(*window) and not any(r.intersects(t) for t in taken)


def badge_size(labels: Sequence[str], px: int, m: Measure) -> tuple[int, int]:
    """Size of the label badge that fits every label (test and reference)."""
    tw = max(m.size(t, px, "bold")[0] for t in labels)
    th = max(m.size(t, px, "bold")[1] for t in labels)
    return tw + 2 * BADGE_PAD[0], th + 2 * BADGE_PAD[1]


def viewing_layout(window: tuple[int, int], video: tuple[int, int], m: Measure, *,
                   labels: Sequence[str], progress: str, hints: Sequence[str],
                   notice: Sequence[str]) -> ViewingLayout:
    """Place the label badge, progress line, hints and notice around the video.

    Text goes into the margins beside, above or below the video, never onto it; what does not
    fit anywhere is left out (hints and notice; they are also on the practice and pause
    screens). ``label`` is None only when the window has no room at all for the badge next to
    the video: the pre-flight refuses such a window.
    """
    vid = video_rect(window, video)
    px = ui_px(window)
    # Keep a gap of GAP pixels around the video free of text.
    taken: list[Rect] = [Rect(vid.x - GAP + 1, vid.y - GAP + 1, vid.w + 2 * GAP - 2,
                              vid.h + 2 * GAP - 2)]
    label = None
    label_px = px + 4
    for lpx in range(px + 4, MIN_PX - 1, -2):
        bw, bh = badge_size(labels, lpx, m)
        candidates = [
            Rect(vid.x - GAP - bw, max(GAP, vid.y), bw, bh),        # left of the video
            Rect(vid.x, vid.y - GAP - bh, bw, bh),                  # above it
            Rect(vid.x, vid.bottom + GAP, bw, bh),                  # below it
            Rect(vid.right + GAP, max(GAP, vid.y), bw, bh),         # right of it
        ]
        label = next((c for c in candidates if _free(c, window, taken)), None)
        if label is not None:
            label_px = lpx
            taken.append(label)
            break

    def place(lines: Sequence[str], spots: Sequence[str]) -> TextBox | None:
        for spx in range(px, MIN_PX - 1, -2):
            bw, bh = _box_extent(lines, spx, m)
            for spot in spots:
                box = _spot(spot, bw, bh, window, vid)
                if box is None:
                    continue
                align = ("right" if spot.endswith("right") else
                         "center" if spot.endswith("center") else "left")
                tb = _stack(lines, spx, m, box.x, box.y, align, box.w)
                if all(_free(r, window, taken) for r in tb.rects):
                    return tb
        return None

    prog = place([progress], ["corner-top-right", "right-top-right", "bottom-right",
                              "top-right", "left-bottom"])
    if prog is not None:
        taken += prog.rects
    hint_box = place(list(hints), ["right-middle", "bottom-center", "left-middle",
                                   "top-center", "left-bottom"]) if hints else None
    if hint_box is not None:
        taken += hint_box.rects
    # The notice replaces the hints while it shows, so it may use their place.
    notice_taken = [r for r in taken if hint_box is None or r not in hint_box.rects]
    notice_box = None
    if notice:
        saved, taken[:] = list(taken), notice_taken
        notice_box = place(list(notice), ["right-middle", "bottom-center", "left-middle",
                                          "top-center", "left-bottom"])
        taken[:] = saved
    return ViewingLayout(window, vid, label, label_px, prog, hint_box, notice_box)


def _spot(spot: str, bw: int, bh: int, window: tuple[int, int], vid: Rect) -> Rect | None:
    """Top-left of a ``bw`` x ``bh`` box at a named place around the video (None if absent)."""
    w, h = window
    right_x0, right_w = vid.right + GAP, w - vid.right - 2 * GAP
    left_w = vid.x - 2 * GAP
    mid_y = max(GAP, (h - bh) // 2)
    spots = {
        "corner-top-right": Rect(w - GAP - bw, GAP, bw, bh),
        "right-top-right": Rect(w - GAP - bw, max(GAP, vid.y), bw, bh),
        "right-middle": Rect(right_x0, mid_y, max(bw, right_w), bh) if right_w >= bw else None,
        "left-middle": Rect(GAP, mid_y, bw, bh) if left_w >= bw else None,
        "left-bottom": Rect(GAP, h - GAP - bh, bw, bh),
        "bottom-right": Rect(w - GAP - bw, h - GAP - bh, bw, bh),
        "bottom-center": Rect((w - bw) // 2, vid.bottom + max(GAP, (h - vid.bottom - bh) // 2),
                              bw, bh),
        "top-center": Rect((w - bw) // 2, max(GAP, (vid.y - bh) // 2), bw, bh),
        "top-right": Rect(w - GAP - bw, max(GAP, (vid.y - bh) // 2), bw, bh),
    }
    r = spots[spot]
    if r is None or r.w < bw:
        return r
    if spot == "right-middle":
        return Rect(r.x, r.y, bw, bh)
    return r


# -- buttons ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Button:
    """A clickable button: what it does (``action``), its text and its rectangle."""

    action: str
    text: str
    rect: Rect
    px: int


def button_rows(items: Sequence[tuple[str, str]], window: tuple[int, int], bottom: int,
                m: Measure, px: int) -> list[Button]:
    """Buttons centred in rows ending at ``bottom``; as many per row as fit the width."""
    w = window[0]
    pad_x, pad_y = round(px * 0.9), round(px * 0.45)
    sizes = [(a, t, m.size(t, px, "bold")) for a, t in items]
    rows: list[list[tuple[str, str, tuple[int, int]]]] = [[]]
    row_w = 0
    gap = round(px * 0.8)
    for a, t, (tw, th) in sizes:
        bw = min(tw + 2 * pad_x, w - 2 * GAP)
        if rows[-1] and row_w + gap + bw > w - 2 * GAP:
            rows.append([])
            row_w = 0
        row_w += (gap if rows[-1] else 0) + bw
        rows[-1].append((a, t, (tw, th)))
    bh = max(th for _, _, (_, th) in sizes) + 2 * pad_y
    out: list[Button] = []
    y = bottom - len(rows) * bh - (len(rows) - 1) * gap // 2
    for row in rows:
        widths = [min(tw + 2 * pad_x, w - 2 * GAP) for _, _, (tw, _) in row]
        total = sum(widths) + gap * (len(row) - 1)
        x = (w - total) // 2
        for (a, t, _), bw in zip(row, widths, strict=True):
            out.append(Button(a, t, Rect(x, y, bw, bh), px))
            x += bw + gap
        y += bh + gap // 2
    return out


# -- the rating screen --------------------------------------------------------------------
@dataclass(frozen=True)
class ScaleLabelBox:
    """One scale label: its tick column and its (possibly wrapped) lines."""

    x: int
    lines: tuple[tuple[str, Rect], ...]


@dataclass(frozen=True)
class RatingLayout:
    """The rating screen: question, slider track, labels, buttons, hints and progress."""

    window: tuple[int, int]
    px: int
    question: TextBox
    track_x0: int
    track_x1: int
    track_y: int
    labels: tuple[ScaleLabelBox, ...]
    label_px: int
    one_row: bool
    buttons: tuple[Button, ...]
    progress: TextBox
    hints: TextBox | None
    notice: TextBox

    @property
    def track(self) -> Rect:
        return Rect(self.track_x0 - 10, self.track_y - 20, self.track_x1 - self.track_x0 + 20,
                    40)

    def button(self, action: str) -> Button:
        return next(b for b in self.buttons if b.action == action)

    def parts(self) -> dict[str, list[Rect]]:
        """Every drawn part's rectangles by name (for overlap checks)."""
        out = {"question": self.question.rects, "track": [self.track],
               "progress": self.progress.rects, "notice": self.notice.rects}
        for i, lab in enumerate(self.labels):
            out[f"label{i}"] = [r for _, r in lab.lines]
        for b in self.buttons:
            out[f"button-{b.action}"] = [b.rect]
        if self.hints is not None:
            out["hints"] = self.hints.rects
        return out


def wrap_words(text: str, width: int, px: int, m: Measure, style: str = "regular"
               ) -> list[str] | None:
    """Greedy wrap into lines no wider than ``width``; None when one word is wider."""
    lines: list[str] = []
    for word in text.split():
        if m.size(word, px, style)[0] > width:
            return None
        if lines and m.size(f"{lines[-1]} {word}", px, style)[0] <= width:
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(word)
    return lines


def wrap_items(items: Sequence[str], width: int, px: int, m: Measure,
               sep: str = "     ") -> list[str]:
    """Join short items ("Enter: submit") into lines, breaking only between items (an item
    wider than a line is word-wrapped on its own)."""
    lines: list[str] = []
    for item in items:
        if lines and m.size(lines[-1] + sep + item, px)[0] <= width:
            lines[-1] += sep + item
        elif m.size(item, px)[0] <= width:
            lines.append(item)
        else:
            lines += wrap_words(item, width, px, m) or [item]
    return lines


def _scale_labels(fracs: Sequence[float], texts: Sequence[str], x0: int, x1: int,
                  window_w: int, m: Measure, px: int) -> tuple[list[list[str]], int, bool]:
    """Wrap each label to the room between its neighbours; smaller text when needed."""
    xs = [x0 + f * (x1 - x0) for f in fracs]
    rooms = []
    for i, x in enumerate(xs):
        left = (x - xs[i - 1]) / 2 if i > 0 else x - GAP
        right = (xs[i + 1] - x) / 2 if i + 1 < len(xs) else window_w - GAP - x
        rooms.append(max(1, int(2 * min(left, right)) - 10))
    # Prefer every label on one line at a slightly smaller size; else wrap, shrinking
    # only as far as the longest single word needs.
    for lpx in range(px, max(MIN_PX, px - 4) - 1, -1):
        if all(m.size(t, lpx)[0] <= r for t, r in zip(texts, rooms, strict=True)):
            return [[t] for t in texts], lpx, True
    for lpx in range(px, MIN_PX - 1, -1):
        wrapped = [wrap_words(t, r, lpx, m) for t, r in zip(texts, rooms, strict=True)]
        if all(w is not None for w in wrapped):
            return [w for w in wrapped if w is not None], lpx, False
    return [[t] for t in texts], MIN_PX, False


def rating_layout(window: tuple[int, int], m: Measure, *, question: str,
                  labels: Sequence[tuple[float, str]], progress: str, hints: Sequence[str],
                  notice: str, buttons: Sequence[tuple[str, str]]) -> RatingLayout:
    """Lay out the rating screen; ``labels`` are (fraction of the scale 0..1, text)."""
    w, h = window
    px = ui_px(window)
    half = min(700, (w - 2 * GAP - 2 * px * 4) // 2)
    cx = w // 2
    x0, x1 = cx - half, cx + half
    fracs = [f for f, _ in labels]
    wrapped, label_px, one_line = _scale_labels(fracs, [t for _, t in labels], x0, x1, w, m,
                                                px)
    qpx = round(px * 1.25)
    qlines = wrap_words(question, w - 4 * GAP, qpx, m) or [question]
    qw, qh = _box_extent(qlines, qpx, m)
    label_lh = round(m.line_height(label_px) * 1.1)
    label_h = max((len(x) for x in wrapped), default=0) * label_lh  # a scale may be unlabelled
    hint_lines = wrap_items(hints, w - 4 * GAP, px - 2, m)
    hw, hh = _box_extent(hint_lines, px - 2, m) if hint_lines else (0, 0)
    prog = _stack([progress], px, m, w - GAP - m.size(progress, px)[0], GAP)
    # Vertical stack: question, track, labels, notice, buttons; hints at the bottom.
    btn_probe = button_rows(buttons, window, 0, m, px)
    btn_h = max(b.rect.bottom for b in btn_probe) - min(b.rect.y for b in btn_probe)
    notice_h = m.size("Ag", px)[1]
    gap = round(px * 1.2)
    block_h = qh + gap + 40 + label_h + gap + notice_h + gap // 2 + btn_h
    top_free = prog.rects[0].bottom + GAP
    bottom_free = h - GAP - (hh + GAP if hint_lines else 0)
    y = max(top_free, top_free + (bottom_free - top_free - block_h) // 2)
    question_box = _stack(qlines, qpx, m, (w - qw) // 2, y, "center", qw)
    track_y = question_box.rects[-1].bottom + gap + 20
    label_boxes = []
    for frac, lines in zip(fracs, wrapped, strict=True):
        x = round(x0 + frac * (x1 - x0))
        rows = []
        for k, text in enumerate(lines):
            tw, th = m.size(text, label_px)
            rows.append((text, Rect(x - tw // 2, track_y + 24 + k * label_lh, tw, th)))
        label_boxes.append(ScaleLabelBox(x, tuple(rows)))
    labels_bottom = track_y + 24 + label_h
    nw = m.size(notice, px)[0]
    notice_box = _stack([notice], px, m, (w - nw) // 2, labels_bottom + gap, "left")
    btns = button_rows(buttons, window, notice_box.rects[0].bottom + gap // 2 + btn_h, m, px)
    hint_box = None
    if hint_lines:
        hint_box = _stack(hint_lines, px - 2, m, (w - hw) // 2, h - GAP - hh, "center", hw)
    return RatingLayout(window, px, question_box, x0, x1, track_y, tuple(label_boxes),
                        label_px, one_line, tuple(btns), prog, hint_box, notice_box)


# -- text screens -------------------------------------------------------------------------
@dataclass(frozen=True)
class TextScreenLayout:
    """A text screen: title, a scrolling text column, a scroll hint and buttons."""

    window: tuple[int, int]
    px: int
    title: TextBox
    column: Rect
    scroll_hint_y: int
    buttons: tuple[Button, ...]
    extra: dict[str, Rect] = field(default_factory=dict)


def text_screen_layout(window: tuple[int, int], m: Measure, *, title: str,
                       buttons: Sequence[tuple[str, str]]) -> TextScreenLayout:
    """Title at the top, buttons at the bottom, the text column in between."""
    w, h = window
    px = ui_px(window)
    tpx = round(px * 1.6)
    tlines = wrap_words(title, w - 4 * GAP, tpx, m, "bold") or [title]
    step = round(m.line_height(tpx, "bold") * 1.1)
    title_lines = []
    y = max(GAP, round(h * 0.04))
    for i, t in enumerate(tlines):
        tw, th = m.size(t, tpx, "bold")
        title_lines.append((t, Rect((w - tw) // 2, y + i * step, tw, th)))
    title_box = TextBox(tpx, tuple(title_lines))
    btns = button_rows(buttons, window, h - max(GAP, round(h * 0.04)), m, px)
    col_w = min(w - 4 * GAP, 38 * px)
    top = title_box.rects[-1].bottom + round(px * 1.2)
    hint_h = m.line_height(px - 2)
    btn_top = min(b.rect.y for b in btns) if btns else h - GAP
    bottom = btn_top - round(px * 0.6) - hint_h - round(px * 0.4)
    column = Rect((w - col_w) // 2, top, col_w, max(0, bottom - top))
    return TextScreenLayout(window, px, title_box, column, bottom + round(px * 0.4),
                            tuple(btns))
