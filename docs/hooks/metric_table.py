"""MkDocs hook: the peer-metrics page's table, generated from the metric registry.

The page holds the marker ``<!-- metric-table -->``; the rows come from
:func:`cgvqm_core.metrics.metric_table_rows`, so a metric added to the registry appears in the
documentation without an edit of the page.
"""

from __future__ import annotations

from typing import Any

MARKER = "<!-- metric-table -->"


def metric_table() -> str:
    from cgvqm_core.metrics import metric_table_rows

    head = ("| metric | name | direction | kind | range | needs weights | devices | "
            "implementation (licence) |\n|---|---|---|---|---|---|---|---|")
    rows = [
        f"| `{r['name']}` | {r['title']} | {r['direction']} | {r['kind']} | {r['range']} | "
        f"{'yes' if r['needs_weights'] else 'no'} | {', '.join(r['devices'])} | "
        f"{r['licence']} |"
        for r in metric_table_rows()
    ]
    return "\n".join([head, *rows])


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    if MARKER in markdown:
        return markdown.replace(MARKER, metric_table())
    return markdown
