"""Drawing the participant's screens from their layouts (needs a GL renderer).

Every text position comes from :mod:`study_app.layout` or a :class:`~.textflow.Flow`; this
module only paints them, so what the tests check is what appears on screen.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from ..layout import Button, RatingLayout, TextBox, TextScreenLayout, ViewingLayout
from .textflow import Flow

if TYPE_CHECKING:
    from ..render import Renderer

Color = tuple[float, float, float, float]
SCREEN_BG: Color = (0.14, 0.15, 0.17, 1.0)
TITLE: Color = (1.0, 1.0, 1.0, 1.0)
BODY: Color = (0.88, 0.89, 0.90, 1.0)
HEADING: Color = (1.0, 1.0, 1.0, 1.0)
ACCENT: Color = (0.98, 0.78, 0.22, 1.0)
DARK: Color = (0.06, 0.06, 0.07, 1.0)
MUTED: Color = (0.62, 0.64, 0.67, 1.0)
ON_GREY: Color = (0.97, 0.97, 0.97, 1.0)  # text on the mid-grey viewing background
# The two labels differ in colour and in kind (a filled box vs. a frame), not only by word.
TEST_FILL: Color = (0.98, 0.76, 0.16, 1.0)
REFERENCE_LINE: Color = (0.36, 0.70, 1.0, 1.0)
REFERENCE_FILL: Color = (0.10, 0.18, 0.30, 1.0)
SLIDER_TRACK: Color = (0.15, 0.15, 0.15, 1.0)
MARKER: Color = (0.85, 0.10, 0.10, 1.0)
ERROR_TEXT: Color = (1.0, 0.55, 0.45, 1.0)
"""Refusals and notices in words: a light red with about 7:1 contrast on the screen
background (the marker's red gave 3:1, and protan participants see saturated red darkest)."""
SUBMIT_READY: Color = (0.16, 0.50, 0.22, 1.0)
SUBMIT_WAIT: Color = (0.42, 0.42, 0.42, 1.0)
LABEL_TEST = "Test video"
LABEL_REFERENCE = "Reference"


def draw_box(r: Renderer, box: TextBox | None, color: Color, style: str = "regular") -> None:
    if box is None:
        return
    for text, rect in box.lines:
        r.text(text, rect.x, rect.y, px=box.px, color=color, style=style)


def draw_button(r: Renderer, b: Button, *, primary: bool, enabled: bool = True,
                hover: bool = False, fill: Color | None = None) -> None:
    x, y, w, h = b.rect.as_tuple()
    if fill is None:
        fill = ACCENT if primary else (0.26, 0.28, 0.31, 1.0)
    if not enabled:
        fill = (0.30, 0.30, 0.32, 1.0)
    if hover and enabled:
        r.rect(x - 3, y - 3, w + 6, h + 6, (1.0, 1.0, 1.0, 0.9))
    r.rect(x, y, w, h, fill)
    text_color = DARK if primary and enabled and fill == ACCENT else (
        (1.0, 1.0, 1.0, 1.0) if enabled else MUTED)
    tw, th = r.text_size(b.text, b.px, "bold")
    r.text(b.text, x + (w - tw) / 2, y + (h - th) / 2, px=b.px, color=text_color,
           style="bold")


def draw_flow(r: Renderer, flow: Flow, x: int, y: int, offset: int, height: int) -> None:
    for line in flow.visible(offset, height):
        if not line.pieces and line.height <= 8:  # a horizontal rule
            r.rect(x, y + line.y - offset + line.height // 2, flow.width, 1, MUTED)
        for p in line.pieces:
            color = HEADING if p.role == "heading" else ACCENT if p.role == "marker" else BODY
            r.text(p.text, x + p.x, y + line.y - offset, px=p.px, color=color, style=p.style)


def draw_text_screen(r: Renderer, lay: TextScreenLayout, flow: Flow, offset: int, *,
                     primary: str | None, disabled: Sequence[str] = (),
                     hover: str | None = None, scroll_hint: str = "") -> None:
    r.clear(SCREEN_BG)
    draw_box(r, lay.title, TITLE, "bold")
    col = lay.column
    draw_flow(r, flow, col.x, col.y, offset, col.h)
    if scroll_hint:
        tw, _ = r.text_size(scroll_hint, lay.px - 2)
        r.text(scroll_hint, (lay.window[0] - tw) / 2, lay.scroll_hint_y, px=lay.px - 2,
               color=ACCENT)
    for b in lay.buttons:
        draw_button(r, b, primary=b.action == primary, enabled=b.action not in disabled,
                    hover=b.action == hover)


# -- viewing ------------------------------------------------------------------------------
def draw_badge(r: Renderer, lay: ViewingLayout, content: str) -> None:
    """The label saying which video shows: a filled yellow box for the test video, a blue
    frame for the reference (colour and kind differ, not just the word)."""
    if lay.label is None:
        return
    x, y, w, h = lay.label.as_tuple()
    px = lay.label_px
    if content == "test":
        r.rect(x, y, w, h, TEST_FILL)
        text, color = LABEL_TEST, DARK
    else:
        r.rect(x, y, w, h, REFERENCE_FILL)
        r.frame(x, y, w, h, 3, REFERENCE_LINE)
        text, color = LABEL_REFERENCE, REFERENCE_LINE
    tw, th = r.text_size(text, px, "bold")
    r.text(text, x + (w - tw) / 2, y + (h - th) / 2, px=px, color=color, style="bold")


def draw_viewing(r: Renderer, lay: ViewingLayout, video: Any, content: str, idx: int, *,
                 notice: bool) -> None:
    """One refresh of the viewing screen: a video frame (or the blank), its label, progress,
    and the hints (or, for two seconds, a notice in their place)."""
    if content != "blank":
        r.draw_video(video, idx, lay.video.x, lay.video.y)
        draw_badge(r, lay, content)
    draw_box(r, lay.progress, ON_GREY)
    draw_box(r, lay.notice if notice else lay.hints, ON_GREY)


def warm_up_viewing(r: Renderer, lay: ViewingLayout, videos: dict[str, Any]) -> None:
    """Draw every variant of the viewing screen once into the back buffer, unshown.

    Drivers compile shader variants and make text textures on first use (Mesa's llvmpipe
    spends 10-50 ms per variant); doing it before the trial's first flip keeps that out of
    the timed presentation, where it showed up as dropped frames.
    """
    for content in ("test", "reference", "blank"):
        for notice in (False, True):
            r.clear()
            video = videos.get(content) or next(iter(videos.values()))
            draw_viewing(r, lay, video, content, video.frame_count - 1, notice=notice)
    r.ctx.finish()
    r.clear()


# -- rating -------------------------------------------------------------------------------
def draw_rating(r: Renderer, lay: RatingLayout, value_x: float | None, *, ready: bool,
                notice: str | None, hover: str | None = None) -> None:
    r.clear()
    draw_box(r, lay.progress, ON_GREY)
    draw_box(r, lay.question, DARK, "regular")
    x0, x1, y = lay.track_x0, lay.track_x1, lay.track_y
    r.rect(x0, y - 3, x1 - x0, 6, SLIDER_TRACK)
    for lab in lay.labels:
        r.rect(lab.x - 1, y - 14, 2, 28, SLIDER_TRACK)
        for text, rect in lab.lines:
            r.text(text, rect.x, rect.y, px=lay.label_px, color=DARK)
    if value_x is not None:
        r.rect(value_x - 7, y - 18, 14, 36, MARKER)
    if notice:
        _, rect = lay.notice.lines[0]
        tw, _ = r.text_size(notice, lay.notice.px)
        r.text(notice, (lay.window[0] - tw) / 2, rect.y, px=lay.notice.px, color=ERROR_TEXT,
               style="bold")
    for b in lay.buttons:
        if b.action == "submit":
            draw_button(r, b, primary=True, enabled=True, hover=hover == "submit",
                        fill=SUBMIT_READY if ready else SUBMIT_WAIT)
        else:
            draw_button(r, b, primary=False, hover=hover == b.action)
    draw_box(r, lay.hints, DARK)
