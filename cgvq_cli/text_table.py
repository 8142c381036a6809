"""Plain-text tables for the terminal: left-aligned columns, one header line, a rule."""

from __future__ import annotations

from collections.abc import Sequence


def format_table(headers: Sequence[str], rows: Sequence[Sequence[object]], *,
                 indent: str = "  ", max_width: int = 60) -> str:
    """Columns as wide as their widest cell (cut at ``max_width`` with an ellipsis)."""
    def cell(value: object) -> str:
        text = "" if value is None else str(value)
        text = " ".join(text.split())  # no line breaks or tabs inside a table
        return text if len(text) <= max_width else text[: max_width - 1] + "…"

    cells = [[cell(h) for h in headers]] + [[cell(v) for v in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = [indent + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
             for r in cells]
    lines.insert(1, indent + "  ".join("-" * w for w in widths))
    return "\n".join(lines)
