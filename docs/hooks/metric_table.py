"""MkDocs hook: the peer-metrics page's table, generated from the metric registry.

The page holds the marker ``<!-- metric-table -->``; the rows come from each registered
entry's spec (:func:`cgvqm_core.metrics.registry.entries`), so a metric added to the registry
appears in the documentation without an edit of the page. Only the spec is read, never
whether a metric can run on the building machine, so the page is the same wherever it is built.
"""

from __future__ import annotations

from typing import Any

MARKER = "<!-- metric-table -->"
HEAD = ("| metric | name | direction | kind | range | needs weights | devices | "
        "implementation (licence) |\n|---|---|---|---|---|---|---|---|")


def _bound(value: float | None, infinite: str) -> str:
    return infinite if value is None else f"{value:g}"


def _row(spec: Any) -> str:
    low, high = spec.value_range
    cells = [f"`{spec.name}`", spec.title, spec.direction, spec.kind,
             f"{_bound(low, '-inf')}..{_bound(high, 'inf')}",
             "yes" if spec.needs_weights else "no", ", ".join(spec.devices), spec.licence]
    return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"


def metric_table() -> str:
    from cgvqm_core.metrics.registry import entries

    return "\n".join([HEAD, *(_row(entry.spec) for entry in entries())])


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    if MARKER in markdown:
        return markdown.replace(MARKER, metric_table())
    return markdown
