"""One text screen on the display (briefing, consent, pause, end, ...) until the participant
chooses one of its actions.

What the screen says comes from :mod:`.screens.content`, its geometry from :mod:`.layout`, the
scrolling and the read-to-the-end rule from :mod:`.screens.text_state`, the drawing from
:mod:`.screens.draw`, and keys and clicks become actions in :mod:`.input_map`. Which screen
follows which stays in :mod:`.app`.
"""

from __future__ import annotations

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
        self.state(spec.name)
        if d.pacer is not None:
            d.pacer.reset()
        while True:
            for event in pg.event.get():
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
            draw_text_screen(d.renderer, lay, flow, st.offset, primary=spec.primary,
                             disabled=st.disabled, hover=hover, scroll_hint=st.hint())
            self.shot(spec.name)
            d.flip()
