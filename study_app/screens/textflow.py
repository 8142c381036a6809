"""Flowing styled text into lines of a given width, and scrolling it by whole lines.

Pure geometry: a ``measure`` object (``size(text, px, style)``, ``line_height(px, style)``;
:class:`study_app.fonts.Fonts` in the app) gives text sizes, so any window from 800x600 up
can be checked without a display. Words too long for a line (file paths) break at ``/`` or
``\\`` or, failing that, between characters; nothing is ever cut off at the edge.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass, field

from ..text_measure import Measure
from .markdown import Block, Run

# Heading sizes relative to body text, by level.
HEADING_SCALE = {1: 1.45, 2: 1.22, 3: 1.08}


@dataclass(frozen=True)
class Piece:
    """Text in one style at ``x`` (relative to the column's left edge) on its line."""

    x: int
    text: str
    px: int
    style: str
    role: str = "body"  # body, heading, marker


@dataclass
class Line:
    """One line of flowed text; ``y`` is its top relative to the text's top."""

    y: int
    height: int
    pieces: list[Piece] = field(default_factory=list)

    @property
    def bottom(self) -> int:
        return self.y + self.height


@dataclass
class Flow:
    """Flowed text: its lines, the column width it was flowed into, and its total height."""

    lines: list[Line]
    width: int
    height: int

    def stops(self, viewport_h: int) -> list[int]:
        """Scroll offsets (line tops) from the start to the first one that shows the end."""
        tops = [ln.y for ln in self.lines] or [0]
        end = max(0, self.height - viewport_h)
        out = [t for t in tops if t < end]
        last = next((t for t in tops if t >= end), tops[-1])
        return [*out, last] if not out or out[-1] != last else out

    def step(self, offset: int, viewport_h: int, lines: int) -> int:
        """The offset ``lines`` stops down (positive) or up (negative) from ``offset``."""
        stops = self.stops(viewport_h)
        i = bisect.bisect_left(stops, offset)
        i = min(len(stops) - 1, max(0, i + lines))
        return stops[i]

    def page(self, offset: int, viewport_h: int, direction: int) -> int:
        """One page down (the first line not fully shown comes to the top) or up."""
        stops = self.stops(viewport_h)
        if direction > 0:
            hidden = [ln.y for ln in self.lines if ln.bottom > offset + viewport_h]
            target = min(hidden[0] if hidden else stops[-1], stops[-1])
        else:
            target = min((s for s in stops if s >= offset - viewport_h), default=0)
        if target == offset:
            return self.step(offset, viewport_h, 1 if direction > 0 else -1)
        return target

    def visible(self, offset: int, viewport_h: int) -> list[Line]:
        """Lines entirely inside the viewport when scrolled to ``offset``."""
        return [ln for ln in self.lines if ln.y >= offset and ln.bottom <= offset + viewport_h]

    def at_end(self, offset: int, viewport_h: int) -> bool:
        return not self.lines or self.lines[-1].bottom <= offset + viewport_h


def _split_long(word: str, px: int, style: str, width: int, m: Measure) -> list[str]:
    """Break a word wider than ``width``: after a path separator if one fits, else anywhere."""
    parts: list[str] = []
    rest = word
    while rest and m.size(rest, px, style)[0] > width:
        cut = 1
        for k in range(1, len(rest) + 1):
            if m.size(rest[:k], px, style)[0] > width:
                break
            cut = k
        seps = [i + 1 for i in range(cut) if rest[i] in "/\\-_."]
        if seps and seps[-1] > cut // 3:
            cut = seps[-1]
        parts.append(rest[:cut])
        rest = rest[cut:]
    if rest:
        parts.append(rest)
    return parts


def flow_runs(runs: Sequence[Run], width: int, m: Measure, *, px: int, y: int = 0,
              indent: int = 0, role: str = "body", first_x: int | None = None,
              line_gap: float = 0.25) -> list[Line]:
    """Greedy word wrap of styled runs into lines starting at ``y``."""
    words: list[tuple[str, str, bool]] = []  # (text, style, space before)
    pending_space = False
    for run in runs:
        chunks = run.text.split(" ")
        for k, chunk in enumerate(chunks):
            if k > 0:
                pending_space = True
            if chunk:
                words.append((chunk, run.style, pending_space and bool(words)))
                pending_space = False
    lh = max(m.line_height(px, st) for st in {"regular"} | {w[1] for w in words})
    step = round(lh * (1 + line_gap))
    lines: list[Line] = []
    line = Line(y, lh)
    x = indent if first_x is None else first_x
    col_w = width
    for text, style, space in words:
        space_w = m.size(" ", px, style)[0] if space and line.pieces else 0
        w = m.size(text, px, style)[0]
        if line.pieces and x + space_w + w > col_w:
            lines.append(line)
            line = Line(line.y + step, lh)
            x, space_w = indent, 0
        if not line.pieces and w > col_w - x:
            parts = _split_long(text, px, style, col_w - x, m)
            for part in parts[:-1]:
                line.pieces.append(Piece(x, part, px, style, role))
                lines.append(line)
                line = Line(line.y + step, lh)
                x = indent
            text = parts[-1]
            w = m.size(text, px, style)[0]
        prev = line.pieces[-1] if line.pieces else None
        if prev is not None and prev.style == style:
            merged = prev.text + (" " if space_w else "") + text
            line.pieces[-1] = Piece(prev.x, merged, px, style, role)
            x = prev.x + m.size(merged, px, style)[0]
        else:
            line.pieces.append(Piece(x + space_w, text, px, style, role))
            x += space_w + w
    if line.pieces or not lines:
        lines.append(line)
    return lines


def flow_blocks(blocks: Sequence[Block], width: int, m: Measure, *, px: int) -> Flow:
    """Lay Markdown blocks out in a column ``width`` pixels wide."""
    lines: list[Line] = []
    y = 0
    gap = round(m.line_height(px) * 0.6)
    for i, block in enumerate(blocks):
        if i > 0:
            y += gap
        if block.kind == "heading":
            hpx = round(px * HEADING_SCALE.get(block.level, 1.0))
            if i > 0:
                y += gap // 2
            runs = [Run(r.text, "bold") for r in block.runs]
            new = flow_runs(runs, width, m, px=hpx, y=y, role="heading")
        elif block.kind == "item":
            indent = block.indent * round(px * 1.5)
            marker_w = m.size(block.marker + " ", px)[0]
            new = flow_runs(block.runs, width, m, px=px, y=y, indent=indent + marker_w)
            new[0].pieces.insert(0, Piece(indent, block.marker, px, "regular", "marker"))
            if i > 0 and blocks[i - 1].kind == "item":
                y -= gap // 2
                for ln in new:
                    ln.y -= gap // 2
        elif block.kind == "rule":
            new = [Line(y, max(2, gap // 2), [])]
        else:
            new = flow_runs(block.runs, width, m, px=px, y=y)
        lines.extend(new)
        y = new[-1].bottom
    return Flow(lines, width, y)


def flow_plain(paragraphs: Sequence[str], width: int, m: Measure, *, px: int,
               style: str = "regular") -> Flow:
    """Plain paragraphs (no Markdown): one block per string, empty strings make a gap."""
    blocks = [Block("paragraph", [Run(p, style)]) for p in paragraphs if p]
    return flow_blocks(blocks, width, m, px=px)
