"""One text screen on the display (briefing, consent, pause, end, ...) until the participant
chooses one of its actions.

What the screen says comes from :mod:`.screens.content`, its geometry from :mod:`.layout`, the
scrolling and the read-to-the-end rule from :mod:`.screens.text_state`, the drawing from
:mod:`.screens.draw`, and keys and clicks become actions in :mod:`.input_map`. Which screen
follows which stays in :mod:`.app`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from .display import Display
from .input_map import button_at, text_screen_action
from .keys import SCROLL, merge
from .layout import text_screen_layout
from .screens.content import ScreenSpec
from .screens.draw import draw_text_screen
from .screens.markdown import parse_markdown
from .screens.text_state import TextScreenState
from .screens.textflow import flow_blocks

INPUT_GRACE_S = 0.5
"""Keys and clicks in a screen's first half second are ignored: a double press on the button
before it (Enter on Submit, twice in 150 ms) would otherwise also choose this screen's action,
and the participant would never see the break or the end screen. Scrolling is not ignored."""

_CHOICE_EVENTS = ("KEYDOWN", "MOUSEBUTTONDOWN", "MOUSEBUTTONUP")
IDLE_REDRAW_S = 0.5
"""A text screen with no input is drawn again twice a second (a window the system uncovered
gets an event and is drawn at once): a pause or end screen left open for an hour costs next
to nothing, where drawing every refresh took 40-47 % of a core in software rendering."""
IDLE_POLL_S = 0.01
"""How often an idle screen looks for input: keys and clicks within 10 ms."""


@dataclass
class TextScreen:
    """Shows text screens on ``display`` for the session around them (the app)."""

    display: Display
    state: Callable[..., None]
    """Logs a screen change (``state(name, **details)``; the end-to-end tests follow it)."""
    shot: Callable[[str], bool]
    """Saves the back buffer once per name when screenshots were asked for."""
    on_close: Callable[[], None]
    """The window's close button on a screen whose close means quitting: the app confirms
    (and stops the run by raising) or returns, and the screen goes on."""

    def show(self, spec: ScreenSpec) -> str:
        """Show ``spec`` until one of its actions is chosen; returns the action."""
        d = self.display
        pg = d.pg
        lay = text_screen_layout(d.size, d.fonts, title=spec.title, buttons=spec.buttons)
        flow = flow_blocks(parse_markdown(spec.body), lay.column.w, d.fonts, px=lay.px)
        st = TextScreenState(spec, flow, lay.column.h)
        keys = merge(spec.keys, SCROLL)
        hover = None
        choice_events = {getattr(pg, name) for name in _CHOICE_EVENTS}
        opens_at = time.monotonic() + INPUT_GRACE_S
        ready = False  # keys and clicks count; the state line says so (tests wait for it)
        if d.pacer is not None:
            d.pacer.reset()
        drawn_at = None  # nothing on a text screen moves: drawn again only on a change
        while True:
            if not ready and time.monotonic() >= opens_at:
                ready = True
                self.state(spec.name)
            events = pg.event.get()
            for event in events:
                if not ready and event.type in choice_events:
                    continue  # too early: the press was meant for the screen before
                if event.type == pg.QUIT and spec.close_action == "quit":
                    self.on_close()  # stops the run (confirmed) or returns to this screen
                    self.state(spec.name)
                    continue
                if event.type == pg.QUIT:
                    action = spec.close_action
                else:
                    action = text_screen_action(pg, event, keys, lay.buttons, d.to_pixels)
                if event.type == pg.MOUSEWHEEL:
                    st.wheel(int(event.y))
                elif event.type == pg.MOUSEMOTION:
                    hover = button_at(lay.buttons, *d.to_pixels(event.pos))
                refused = len(st.refusals)
                outcome = st.handle(action)
                if len(st.refusals) > refused:
                    self.state(f"{spec.name}-scroll", reason="read-to-end")
                if outcome is not None:
                    self.state(f"{spec.name}-done", choice=outcome)
                    return outcome
            now = time.monotonic()
            if not events and drawn_at is not None and now - drawn_at < IDLE_REDRAW_S:
                time.sleep(IDLE_POLL_S)  # an idle screen: no draw, no flip
                continue
            draw_text_screen(d.renderer, lay, flow, st.offset, primary=spec.primary,
                             disabled=st.disabled, hover=hover, scroll_hint=st.hint())
            self.shot(spec.name)
            d.flip()
            drawn_at = now
