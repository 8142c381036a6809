"""A text screen's state (pure): where it is scrolled, whether the text was read to the end,
and which chosen action ends the screen. :mod:`study_app.text_screen` maps keys, clicks and
the wheel to actions and draws; the rules (e.g. consent is given only after reading to the
end) live here."""

from __future__ import annotations

from dataclasses import dataclass, field

from .content import ScreenSpec
from .textflow import Flow

SCROLL_ACTIONS = ("scroll_up", "scroll_down", "page_up", "page_down", "home", "end")


@dataclass
class TextScreenState:
    spec: ScreenSpec
    flow: Flow
    view_h: int
    offset: int = 0
    seen_end: bool = False
    refusals: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.seen_end = self.flow.at_end(self.offset, self.view_h)

    def handle(self, action: str | None) -> str | None:
        """Apply an action; returns the screen's outcome when the action ends it."""
        f, h = self.flow, self.view_h
        if action is None:
            return None
        if action in ("scroll_up", "scroll_down"):
            self.offset = f.step(self.offset, h, 1 if action == "scroll_down" else -1)
        elif action in ("page_up", "page_down"):
            self.offset = f.page(self.offset, h, 1 if action == "page_down" else -1)
        elif action in ("home", "end"):
            self.offset = 0 if action == "home" else f.stops(h)[-1]
        elif action in {a for a, _ in self.spec.buttons}:
            if action in self.spec.needs_end and not self.seen_end:
                # Not yet: the text must be read to its end first; show the next page.
                self.refusals.append(action)
                self.offset = f.page(self.offset, h, 1)
            else:
                return action
        elif action == self.spec.close_action:
            return action
        self.seen_end = self.seen_end or f.at_end(self.offset, h)
        return None

    def wheel(self, notches: int) -> None:
        """Mouse wheel: positive notches scroll up (as SDL reports them)."""
        self.offset = self.flow.step(self.offset, self.view_h, -3 * notches)
        self.seen_end = self.seen_end or self.flow.at_end(self.offset, self.view_h)

    @property
    def at_end(self) -> bool:
        return self.flow.at_end(self.offset, self.view_h)

    @property
    def disabled(self) -> list[str]:
        return [] if self.seen_end else sorted(self.spec.needs_end)

    def hint(self) -> str:
        if self.at_end:
            return ""
        if self.spec.needs_end and not self.seen_end:
            return "Please read to the end (mouse wheel, ↓ or Page Down) to continue"
        return "More below: scroll with the mouse wheel, ↓ or Page Down"
