"""How the stimuli were shown, in the words of a paper's Methods: the player's protocol and
the display the pre-flight required (from the manifest), and what the session files recorded
about timing (vsync, dropped frames). Only for ratings from this toolkit's session files: a
ratings CSV may come from another tool, whose presentation the manifest does not describe."""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from .data import RatingSet


def presentation(manifest: Any) -> dict[str, Any]:
    """The manifest's facts the paragraph uses (kept on the :class:`RatingSet`)."""
    p, d = manifest.protocol, manifest.display
    return {"blank_seconds": float(p.blank_seconds), "loop": bool(p.loop),
            "min_view_seconds": p.min_view_seconds, "min_width": int(d.min_width),
            "min_height": int(d.min_height), "min_refresh_hz": float(d.min_refresh_hz),
            "hidden_reference": bool(p.hidden_reference)}


def _sessions(quality: pd.DataFrame | None, raters: list[str]) -> str:
    """What the used raters' session files say about timing, in one sentence."""
    if quality is None or not raters or "timing_mode" not in quality.columns:
        return ""
    q = quality.reindex(raters)
    modes = q["timing_mode"].fillna("").astype(str)
    if modes.str.contains("simulated").all():
        return " These sessions were simulated (no display was involved)."
    n = len(raters)
    vsync = int((q["vsync"] == True).sum()) if "vsync" in q.columns else 0  # noqa: E712
    text = (f" All {n} sessions ran with vsync" if vsync == n else
            f" {vsync} of the {n} sessions ran with vsync")
    shown = pd.to_numeric(q.get("presentations"), errors="coerce").sum()
    dropped = pd.to_numeric(q.get("trials_with_drops"), errors="coerce").sum()
    if shown and math.isfinite(shown):
        text += (f"; {int(dropped)} of {int(shown)} presentations ({dropped / shown:.1%}) "
                 "dropped a frame or more")
    return text + "."


def presentation_paragraph(rs: RatingSet, quality: pd.DataFrame | None,
                           used: list[str]) -> str:
    """The paragraph, or "" when the ratings did not come from this toolkit's player."""
    p = rs.presentation
    info = rs.rater_info
    if not p or info is None or "files" not in info.columns or not info["files"].notna().any():
        return ""
    view = ("one loop" if p["min_view_seconds"] is None else f"{p['min_view_seconds']:g} s")
    text = ("Stimuli were shown in the toolkit's player at their native resolution (one video "
            "pixel per screen pixel). Each trial " + ("looped" if p["loop"] else "played")
            + " the test video and its reference, frame-accurately, and the participant "
            f"switched between them with the Space key; every switch showed a "
            f"{p['blank_seconds']:g} s grey blank. The rating could be given after {view}"
            + (", and each source's reference was also rated as a hidden reference"
               if p["hidden_reference"] else "")
            + f". A pre-flight check before the session required a display of at least "
            f"{p['min_width']}x{p['min_height']} pixels at {p['min_refresh_hz']:g} Hz or more.")
    return text + _sessions(quality, used)
