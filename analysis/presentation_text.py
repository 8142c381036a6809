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
            "hidden_reference": bool(p.hidden_reference),
            "viewing_distance_cm": p.viewing_distance_cm}


def _column(quality: pd.DataFrame, raters: list[str], name: str) -> pd.Series:
    if name not in quality.columns:
        return pd.Series(dtype=float)
    return quality.reindex(raters)[name]


def _displays(quality: pd.DataFrame | None, raters: list[str]) -> str:
    """The participants' screens (pixels, refresh) as their pre-flights measured them."""
    if quality is None:
        return ""
    sizes = [tuple(int(v) for v in size.split("x"))
             for cell in _column(quality, raters, "screen").dropna().astype(str)
             for size in cell.split(", ") if size.count("x") == 1]
    if not sizes:
        return ""
    sizes.sort(key=lambda wh: (wh[0] * wh[1], wh))
    name = [f"{w}x{h}" for w, h in sizes]
    common = pd.Series(name).value_counts()
    text = (f" The participants' screens had {name[0]} pixels" if name[0] == name[-1] else
            f" The participants' screens had {name[0]} to {name[-1]} pixels"
            + (f" ({common.index[0]} most often)" if common.iloc[0] > 1 and
               (len(common) == 1 or common.iloc[0] > common.iloc[1]) else ""))
    hz = pd.to_numeric(_column(quality, raters, "refresh_hz"), errors="coerce").dropna()
    if len(hz):
        lo, hi = f"{hz.min():.0f}", f"{hz.max():.0f}"
        text += f" and refreshed at {lo} Hz" if lo == hi else f" and refreshed at {lo}-{hi} Hz"
    return text + "."


def _seating(p: dict[str, Any], quality: pd.DataFrame | None, raters: list[str]) -> str:
    """The instructed viewing distance and, where the card calibration measured the screen,
    the pixels per visual degree it gave."""
    cm = p.get("viewing_distance_cm")
    if cm is None:
        return ""
    text = (f" Participants were asked to sit with their eyes about {cm:g} cm from the screen "
            "while they rated (the player said so before the trials and after each break; the "
            "distance itself was not measured).")
    if quality is None:
        return text
    ppd = pd.to_numeric(_column(quality, raters, "px_per_degree"), errors="coerce").dropna()
    if len(ppd):
        of = f"all {len(raters)}" if len(ppd) == len(raters) else f"{len(ppd)} of the {len(raters)}"
        spread = (f"{ppd.iloc[0]:.0f} pixels per visual degree" if len(ppd) == 1 else
                  f"{ppd.min():.0f}-{ppd.max():.0f} pixels per visual degree (median "
                  f"{ppd.median():.0f})")
        text += (f" At that distance the screens of {of} participants, whose pixel size the "
                 f"vision screening measured with a bank card, showed {spread}.")
    return text


def _text(column: pd.Series) -> pd.Series:
    """A column as text, "" for a gap (a column of NaN is float: no "" fill)."""
    return column.map(lambda v: "" if pd.isna(v) else str(v))


def pilot_raters(quality: pd.DataFrame | None, raters: list[str]) -> list[str]:
    """The raters among ``raters`` whose sessions were paced without vsync (pilots)."""
    if quality is None or "timing_mode" not in quality.columns:
        return []
    modes = _text(quality.reindex(raters)["timing_mode"])
    return [str(r) for r in modes.index[modes.str.contains("paced")]]


def _sessions(quality: pd.DataFrame | None, raters: list[str]) -> str:
    """What the used raters' session files say about timing, in one sentence (simulated
    sessions, which had no display, are not counted)."""
    if quality is None or not raters or "timing_mode" not in quality.columns:
        return ""
    q = quality.reindex(raters)
    simulated = _text(q["timing_mode"]).str.contains("simulated")
    if simulated.all():
        return " These sessions were simulated (no display was involved)."
    aside = (f" ({int(simulated.sum())} simulated sessions, which had no display, are not "
             "counted)" if simulated.any() else "")
    q = q[~simulated]
    n = len(q)
    vsync = int((q["vsync"] == True).sum()) if "vsync" in q.columns else 0  # noqa: E712
    text = (f" All {n} sessions ran with vsync" if vsync == n else
            f" {vsync} of the {n} sessions ran with vsync")
    shown = pd.to_numeric(q.get("presentations"), errors="coerce").sum()
    dropped = pd.to_numeric(q.get("trials_with_drops"), errors="coerce").sum()
    if shown and math.isfinite(shown):
        text += (f"; {int(dropped)} of {int(shown)} presentations ({dropped / shown:.1%}) "
                 "dropped a frame or more")
    pilots = pilot_raters(q, list(q.index))
    if pilots:
        text += (f"; {len(pilots)} of them ran paced on the clock without vsync (pilots: "
                 f"{', '.join(pilots)})")
    return text + aside + "."


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
    return text + _displays(quality, used) + _seating(p, quality, used) + _sessions(quality, used)


def viewing_summary(rs: RatingSet, quality: pd.DataFrame | None, raters: list[str],
                    metric_ppd: dict[str, float]) -> dict[str, Any]:
    """summary.json's ``viewing``: the seating distance, the used raters' pixels per degree at
    it (where measured), and the pixels per degree each metric's scores were computed at."""
    ppd = pd.Series(dtype=float)
    if quality is not None:
        ppd = pd.to_numeric(_column(quality, raters, "px_per_degree"), errors="coerce").dropna()
    return {"seating_cm": (rs.presentation or {}).get("viewing_distance_cm"),
            "panel_ppd": ({"n": len(ppd), "min": float(ppd.min()),
                           "median": float(ppd.median()), "max": float(ppd.max())}
                          if len(ppd) else None),
            "metric_ppd": dict(metric_ppd)}


def metric_viewing_text(viewing: dict[str, Any] | None) -> tuple[str, str]:
    """At what pixels per degree the metrics were computed, against the panel's (a sentence
    for the paper); and advice when a metric was computed outside the panel's range, so that
    no participant saw the stimuli like it ("" when none was)."""
    if not viewing or not viewing.get("metric_ppd"):
        return "", ""
    by_value: dict[float, list[str]] = {}
    for metric, ppd in viewing["metric_ppd"].items():
        by_value.setdefault(round(float(ppd), 1), []).append(metric)
    text = "Viewing condition: " + "; ".join(
        f"{', '.join(ms)} {'was' if len(ms) == 1 else 'were'} computed at {v:g} pixels per "
        "visual degree" for v, ms in by_value.items())
    panel = viewing.get("panel_ppd")
    if not panel:
        return text + (". The participants' pixels per degree were not measured (a seating "
                       "distance and the vision screening's acuity check measure them)."), ""
    spread = (f"{panel['median']:.0f}" if panel["n"] == 1 else
              f"{panel['min']:.0f}-{panel['max']:.0f} (median {panel['median']:.0f})")
    who = ("the participant whose screen the card calibration measured saw" if panel["n"] == 1
           else f"the {panel['n']} participants whose screens the card calibration measured saw")
    text += f"; at the instructed {viewing['seating_cm']:g} cm, {who} {spread}."
    off = [m for m, v in viewing["metric_ppd"].items()
           if not panel["min"] - 0.5 <= v <= panel["max"] + 0.5]
    advice = (f"No measured participant saw the stimuli at the pixels per degree of "
              f"{', '.join(off)}: rescore with --ppd {panel['median']:.0f} to compare under the "
              "panel's viewing condition." if off else "")
    return text, advice
