"""How the screen geometry asks for text sizes, without depending on a font or a display.

The layout (:mod:`study_app.layout`) and the text flow of the screens
(:mod:`study_app.screens.textflow`) both take a ``Measure``: the shipped font's real metrics in
the app (:class:`study_app.fonts.Fonts`), any object with the same two methods in the tests.
"""

from __future__ import annotations

from typing import Protocol


class Measure(Protocol):
    def size(self, text: str, px: int, style: str = "regular") -> tuple[int, int]: ...

    def line_height(self, px: int, style: str = "regular") -> int: ...
