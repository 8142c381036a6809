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
            "viewing_distance_cm": p.viewing_distance_cm,
            "videos": [{"width": r.width, "height": r.height, "fps": r.fps, "frames": r.frames}
                       for r in manifest.references]}


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


def _impairment(rs: RatingSet) -> bool:
    """Whether the scale's labels are the impairment scale's (P.910 DCR, P.913)."""
    return any(t.strip().lower() == "imperceptible" for _, t in rs.scale_labels)


def _videos(p: dict[str, Any]) -> str:
    """The references' size, length and frame rate (the test videos match them)."""
    videos = [v for v in p.get("videos") or [] if v.get("width") and v.get("fps")
              and v.get("frames")]
    if not videos:
        return ""
    sizes = list(dict.fromkeys(f"{v['width']}x{v['height']}" for v in videos))
    seconds = sorted({round(v["frames"] / v["fps"], 2) for v in videos})
    rates = sorted({float(v["fps"]) for v in videos})
    length = (f"{seconds[0]:g} s" if len(seconds) == 1 else
              f"{seconds[0]:g}-{seconds[-1]:g} s")
    return (f" The videos were {_join(sizes)} pixels and {length} long, at "
            f"{_join([f'{r:g}' for r in rates])} frames per second.")


def _join(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def uneven_refresh(hz: float, rates: list[float]) -> bool:
    """Whether a display at ``hz`` holds some frame of a ``rates`` video for more refreshes
    than another (a refresh rate that is not a whole multiple of the frame rate, within 1%:
    59.94 Hz shows 60 fps evenly but for one repeat every 17 s)."""
    return any(abs(hz / fps - round(hz / fps)) > 0.01 * (hz / fps) or round(hz / fps) < 1
               for fps in rates if fps > 0)


def _cadence(p: dict[str, Any], quality: pd.DataFrame | None, raters: list[str]) -> str:
    """How many participants' refresh rates could not show the videos' frame rates evenly."""
    rates = sorted({float(v["fps"]) for v in p.get("videos") or [] if v.get("fps")})
    if quality is None or not rates:
        return ""
    hz = pd.to_numeric(_column(quality, raters, "refresh_hz"), errors="coerce").dropna()
    if not len(hz):
        return ""
    uneven = hz[[uneven_refresh(float(h), rates) for h in hz]]
    fps = _join([f"{r:g}" for r in rates]) + " fps"
    if not len(uneven):
        return (f" Every measured refresh rate was a whole multiple of {fps}, so each video "
                "frame was shown for the same number of refreshes.")
    span = (f"{uneven.min():.0f} Hz" if round(uneven.min()) == round(uneven.max()) else
            f"{uneven.min():.0f}-{uneven.max():.0f} Hz")
    return (f" On the screens of {len(uneven)} of the {len(hz)} participants whose refresh "
            f"rate was measured ({span}) it was not a whole multiple of the videos' {fps}: "
            "video frames were held for unequal numbers of refreshes there (uneven motion).")


def _angle(p: dict[str, Any], quality: pd.DataFrame | None, raters: list[str]) -> str:
    """The widest video's width in visual degrees at the instructed distance, on the
    screens whose pixel size the card calibration measured."""
    widths = [int(v["width"]) for v in p.get("videos") or [] if v.get("width")]
    if quality is None or not widths or p.get("viewing_distance_cm") is None:
        return ""
    ppd = pd.to_numeric(_column(quality, raters, "px_per_degree"), errors="coerce").dropna()
    if not len(ppd):
        return ""
    deg = max(widths) / ppd
    spread = (f"{deg.iloc[0]:.1f} degrees of visual angle horizontally" if len(deg) == 1 else
              f"{deg.min():.1f}-{deg.max():.1f} degrees of visual angle horizontally "
              f"(median {deg.median():.1f})")
    widest = "The videos" if len(set(widths)) == 1 else "The widest videos"
    return f" {widest} ({max(widths)} pixels wide) thus spanned {spread}."


def _order(quality: pd.DataFrame | None, raters: list[str]) -> str:
    """Practice, order, breaks and the time in the study, from the session files (of people:
    simulated sessions have no order a person saw, nor time)."""
    if quality is None or not raters:
        return ""
    modes = _text(quality.reindex(raters)["timing_mode"]) if "timing_mode" in \
        quality.columns else pd.Series("", index=raters)
    raters = [r for r in raters if "simulated" not in modes.get(r, "")]
    if not raters:
        return ""
    practice = pd.to_numeric(_column(quality, raters, "practice_trials"),
                             errors="coerce").dropna()
    breaks = pd.to_numeric(_column(quality, raters, "break_every"), errors="coerce").dropna()
    parts = []
    if len(practice) and practice.nunique() == 1 and practice.iloc[0] > 0:
        k = int(practice.iloc[0])
        parts.append(f"{k} practice trial{'s' if k != 1 else ''} (not rated) came first")
    parts.append("each participant saw the trials in their own random order, never the same "
                 "stimulus twice in a row")
    if len(breaks) and breaks.nunique() == 1:
        every = int(breaks.iloc[0])
        parts.append(f"a break was offered every {every} trials" if every > 0 else
                     "no breaks were offered")
    text = " " + "; ".join(parts)
    minutes = pd.to_numeric(_column(quality, raters, "minutes"), errors="coerce").dropna()
    if len(minutes):
        spread = (f"{minutes.iloc[0]:.0f} min" if len(minutes) == 1 else
                  f"a median of {minutes.median():.0f} min ({minutes.min():.0f}-"
                  f"{minutes.max():.0f})")
        text += f". The participants spent {spread} in the study, breaks included"
    return text[0] + text[1].upper() + text[2:] + "."


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
    text = (f" The sessions of all {n} participants ran with vsync" if vsync == n else
            f" The sessions of {vsync} of the {n} participants ran with vsync")
    shown = pd.to_numeric(q.get("presentations"), errors="coerce").sum()
    dropped = pd.to_numeric(q.get("trials_with_drops"), errors="coerce").sum()
    if shown and math.isfinite(shown):
        text += (f"; {int(dropped)} of the {int(shown)} presentations in their session files "
                 f"({dropped / shown:.1%}) dropped a frame or more")
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
            + " the test video and its reference in step (a switch showed the other video at "
            "the same frame), and the participant "
            f"switched between them with the Space key; every switch showed a "
            f"{p['blank_seconds']:g} s grey blank. The rating could be given after {view}"
            + (", and each source's reference was also rated as a hidden reference"
               if p["hidden_reference"] else "")
            + ". The method is a double-stimulus rating with free switching between the test "
            "video and its reference" + (" on an impairment scale (a variant of ITU-T P.910's "
                                         "DCR)" if _impairment(rs) else "")
            + f". A pre-flight check before the session required a display of at least "
            f"{p['min_width']}x{p['min_height']} pixels at {p['min_refresh_hz']:g} Hz or more.")
    return (text + _videos(p) + _displays(quality, used) + _cadence(p, quality, used)
            + _seating(p, quality, used) + _angle(p, quality, used) + _sessions(quality, used)
            + _order(quality, used))


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


def metric_viewing_text(viewing: dict[str, Any] | None,
                        titles: dict[str, str] | None = None) -> tuple[str, str]:
    """At what pixels per degree the metrics were computed, against the panel's (a sentence
    for the paper); and advice when a metric was computed outside the panel's range, so that
    no participant saw the stimuli like it ("" when none was). ``titles``: metric -> the
    name prose prints (the summary's ``metric_titles``)."""
    if not viewing or not viewing.get("metric_ppd"):
        return "", ""
    titles = titles or {}
    by_value: dict[float, list[str]] = {}
    for metric, ppd in viewing["metric_ppd"].items():
        by_value.setdefault(round(float(ppd), 1), []).append(titles.get(metric, metric))
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
    off = [titles.get(m, m) for m, v in viewing["metric_ppd"].items()
           if not panel["min"] - 0.5 <= v <= panel["max"] + 0.5]
    if not off:
        return text, ""
    text += (f" No measured participant saw the stimuli at the pixels per degree of "
             f"{', '.join(off)}.")
    return text, (f"Rescore with --ppd {panel['median']:.0f} to compare under the panel's "
                  "viewing condition.")
