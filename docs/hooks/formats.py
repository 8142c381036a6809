"""MkDocs hook: the file-format reference, generated from the code that reads and writes.

Markers on the file-formats page are replaced by what the code defines, so the page cannot
drift from the contracts: the manifest's fields (its pydantic models), the session file's
tables (its DDL), the CSV tables (:mod:`stimuli_manifests.tables`), the upload protocol's
constants and the invite file's keys.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Any

from pydantic import BaseModel


def _type_text(annotation: Any) -> str:
    plain = getattr(annotation, "__args__", None) is None
    text = annotation.__name__ if plain and hasattr(annotation, "__name__") else str(annotation)
    text = re.sub(r"\b(typing|stimuli_manifests\.model)\.", "", text)
    return text.replace("|", "or").replace("[", "\\[")


def _model_table(model: type[BaseModel]) -> str:
    rows = ["| field | type | default | notes |", "|---|---|---|---|"]
    for name, field in model.model_fields.items():
        if field.is_required():
            default = "required"
        elif field.default_factory is not None:
            made = field.default_factory()
            default = ("its defaults (below)" if isinstance(made, BaseModel)
                       else f"{len(made)} entries" if made else "empty")
        else:
            default = f"`{field.default!r}`"
        limits = ", ".join(re.sub(r"^\w+\((.*)\)$", r"\1", str(m)) for m in field.metadata)
        notes = "; ".join(x for x in (field.description or "", limits) if x)
        rows.append(f"| `{name}` | {_type_text(field.annotation)} | {default} | {notes} |")
    return "\n".join(rows)


def manifest_section() -> str:
    from stimuli_manifests import model

    parts = [f"Format value: `{model.MANIFEST_FORMAT.version}` (field `format`)."]
    for cls in (model.Manifest, model.RatingScale, model.ScaleLabel, model.Protocol,
                model.DisplayRequirements, model.Reference, model.Condition):
        parts += [f"**{cls.__name__}**" + (f": {cls.__doc__.strip().splitlines()[0]}"
                                           if cls.__doc__ else ""), "", _model_table(cls), ""]
    from stimuli_manifests import panel

    parts += [f"The `panel` block: format value `{panel.PANEL_FORMAT.version}` (field "
              "`format`); see [Describing the panel](panel.md).", ""]
    for cls in (panel.Panel, panel.Questionnaire, panel.Page, panel.VisionScreening):
        parts += [f"**{cls.__name__}**" + (f": {cls.__doc__.strip().splitlines()[0]}"
                                           if cls.__doc__ else ""), "", _model_table(cls), ""]
    return "\n".join(parts)


def session_section() -> str:
    from session_store import schema

    return (f"Format value: `{schema.SCHEMA_VERSION}` (table `meta`, key `schema`). "
            "The tables, as created:\n\n```sql\n" + schema.DDL.strip() + "\n"
            + schema.PANEL_DDL.strip() + "\n```")


def tables_section() -> str:
    from stimuli_manifests import tables

    parts = []
    for fmt in (v for v in vars(tables).values() if isinstance(v, tables.TableFormat)):
        parts += [f"### {fmt.what or fmt.name} (`{fmt.version}`)", "",
                  "Required columns: " + ", ".join(f"`{c}`" for c in fmt.required) + ".", ""]
        if fmt.optional:
            parts += ["Optional columns: " + ", ".join(f"`{c}`" for c in fmt.optional) + ".",
                      ""]
        parts += [f"Last column: `{tables.FORMAT_COLUMN}` = `{fmt.version}` on every row.", ""]
    return "\n".join(parts)


def upload_section() -> str:
    from session_store import protocol

    constants = [f"| `{k}` | `{v!r}` |" for k, v in vars(protocol).items()
                 if k.isupper() and isinstance(v, int | float | str)]
    return "\n".join([protocol.__doc__.strip(), "", "| constant | value |", "|---|---|",
                      *constants])


def invite_section() -> str:
    from session_store import invite

    keys = ["format", *(f.name for f in dataclasses.fields(invite.Invite))]
    return (f"A JSON object `<participant>{invite.INVITE_SUFFIX}` with the keys "
            + ", ".join(f"`{k}`" for k in keys) + f"; `format` is `{invite.INVITE_FORMAT}`.")


SECTIONS = {
    "manifest": manifest_section,
    "session": session_section,
    "tables": tables_section,
    "upload": upload_section,
    "invite": invite_section,
}


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    for name, build in SECTIONS.items():
        marker = f"<!-- format:{name} -->"
        if marker in markdown:
            markdown = markdown.replace(marker, build())
    return markdown
