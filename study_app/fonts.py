"""The font shipped with the app (DejaVu Sans, see ``assets/fonts/LICENSE.txt``).

Every participant sees the same glyphs and spacing whatever fonts their system has; the
default Pygame font set body text with uneven letter spacing ("at  least", "stu dy").
:class:`Fonts` opens each (style, pixel size) once and measures text without a display, so
layout code can be tested headless with the real metrics.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pygame

FONT_DIR = Path(__file__).resolve().parent / "assets" / "fonts"
FONT_FILES = {
    "regular": "DejaVuSans.ttf",
    "bold": "DejaVuSans-Bold.ttf",
    "italic": "DejaVuSans-Oblique.ttf",
}
STYLES = tuple(FONT_FILES)


def font_path(style: str = "regular") -> Path:
    """The file of a font style (``regular``, ``bold`` or ``italic``)."""
    return FONT_DIR / FONT_FILES[style]


class Fonts:
    """Open fonts by (style, pixel size); measure and render text with them."""

    def __init__(self) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        import pygame

        pygame.font.init()
        self._pg = pygame
        self._open: dict[tuple[str, int], pygame.font.Font] = {}

    def font(self, px: int, style: str = "regular") -> pygame.font.Font:
        key = (style, int(px))
        if key not in self._open:
            self._open[key] = self._pg.font.Font(str(font_path(style)), int(px))
        return self._open[key]

    def size(self, text: str, px: int, style: str = "regular") -> tuple[int, int]:
        """Width and height in pixels of ``text`` set in one line."""
        return self.font(px, style).size(text)

    def line_height(self, px: int, style: str = "regular") -> int:
        return self.font(px, style).get_linesize()
