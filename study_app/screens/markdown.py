"""Basic Markdown for briefing and consent texts: headings, paragraphs, lists, bold, italics.

Just what study texts use, parsed into blocks of styled runs (no HTML, no tables). Links show
their text followed by the address in brackets, so nothing the experimenter wrote is lost on
a screen that cannot be clicked through to a browser.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
_BULLET = re.compile(r"^(\s*)[-*+]\s+(.*)$")
_NUMBERED = re.compile(r"^(\s*)(\d{1,3})[.)]\s+(.*)$")
_RULE = re.compile(r"^\s*([-*_])(\s*\1){2,}\s*$")
_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")


@dataclass(frozen=True)
class Run:
    """A piece of text in one style: ``regular``, ``bold`` or ``italic``."""

    text: str
    style: str = "regular"


@dataclass
class Block:
    """A heading (``level`` 1-6), a paragraph, or a list ``item`` (``marker`` "•" or "3.")."""

    kind: str
    runs: list[Run] = field(default_factory=list)
    level: int = 0
    marker: str = ""
    indent: int = 0

    @property
    def text(self) -> str:
        return "".join(r.text for r in self.runs)


def parse_inline(text: str) -> list[Run]:
    """Split a line into runs: ``**bold**``/``__bold__``, ``*italic*``/``_italic_``."""
    text = _LINK.sub(lambda m: f"{m.group(1)} ({m.group(2)})", text)
    text = text.replace("`", "")
    runs: list[Run] = []
    buf: list[str] = []
    bold = italic = False
    i = 0

    def flush() -> None:
        if buf:
            style = "bold" if bold else "italic" if italic else "regular"
            runs.append(Run("".join(buf), style))
            buf.clear()

    while i < len(text):
        c = text[i]
        if c == "\\" and i + 1 < len(text) and text[i + 1] in "\\*_#-+.[]()`":
            buf.append(text[i + 1])
            i += 2
            continue
        if c in "*_":
            double = text[i:i + 2] == c * 2
            width = 2 if double else 1
            before = text[i - 1] if i > 0 else " "
            after = text[i + width] if i + width < len(text) else " "
            # '_' inside a word (snake_case, file_name.md) is a letter, not emphasis.
            if c == "_" and before.isalnum() and after.isalnum():
                buf.append(c)
                i += 1
                continue
            opens = not after.isspace()
            closes = not before.isspace()
            if double and ((bold and closes) or (not bold and opens
                           and text.find(c * 2, i + 2) > i + 2)):
                flush()
                bold = not bold
                i += 2
                continue
            if not double and ((italic and closes) or (not italic and opens
                               and text.find(c, i + 1) > i + 1)):
                flush()
                italic = not italic
                i += 1
                continue
        buf.append(c)
        i += 1
    flush()
    return _merge(runs)


def _merge(runs: list[Run]) -> list[Run]:
    out: list[Run] = []
    for run in runs:
        if out and out[-1].style == run.style:
            out[-1] = Run(out[-1].text + run.text, run.style)
        elif run.text:
            out.append(run)
    return out


def parse_markdown(text: str) -> list[Block]:
    """Blocks of a Markdown text; consecutive lines of a paragraph or item are joined."""
    blocks: list[Block] = []
    para: list[str] = []
    item: Block | None = None
    item_lines: list[str] = []

    def end_para() -> None:
        nonlocal para
        if para:
            blocks.append(Block("paragraph", parse_inline(" ".join(para))))
            para = []

    def end_item() -> None:
        nonlocal item, item_lines
        if item is not None:
            item.runs = parse_inline(" ".join(item_lines))
            blocks.append(item)
            item, item_lines = None, []

    for raw in text.replace("\r\n", "\n").split("\n"):
        line = raw.rstrip()
        if not line.strip():
            end_para()
            end_item()
            continue
        if _RULE.match(line):
            end_para()
            end_item()
            blocks.append(Block("rule"))
            continue
        if m := _HEADING.match(line.strip()):
            end_para()
            end_item()
            blocks.append(Block("heading", parse_inline(m.group(2)), level=len(m.group(1))))
            continue
        bullet, numbered = _BULLET.match(line), _NUMBERED.match(line)
        if bullet or numbered:
            end_para()
            end_item()
            lead = (bullet or numbered).group(1).expandtabs(4)
            marker = "•" if bullet else f"{numbered.group(2)}."
            item = Block("item", marker=marker, indent=min(2, len(lead) // 2))
            item_lines = [(bullet.group(2) if bullet else numbered.group(3)).strip()]
            continue
        if item is not None:
            item_lines.append(line.strip())
        else:
            para.append(line.strip())
    end_para()
    end_item()
    return blocks
