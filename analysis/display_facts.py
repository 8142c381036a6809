"""What the session files say about how each participant saw the stimuli: the screen and
refresh rate the pre-flight measured, the seating distance the player told, and the pixel
density the vision screening's card calibration measured, hence the pixels per visual degree
at that distance (what FLIP and ColorVideoVDP take as ``--ppd``)."""

from __future__ import annotations

from typing import Any

import numpy as np

GEOMETRY_KEYS = ("px_per_mm", "px_per_degree", "viewing_distance_cm")


def _screens(recs: list) -> str:
    """The participant's screen(s) in pixels as the pre-flight measured them ("" if none)."""
    sizes = []
    for r in recs:
        screen = (r.info.display or {}).get("screen")
        if isinstance(screen, list) and len(screen) == 2:
            sizes.append(f"{int(screen[0])}x{int(screen[1])}")
    return ", ".join(dict.fromkeys(sizes))


def _refresh_hz(recs: list) -> float:
    """The refresh rate of the participant's session that holds the most ratings among
    those that measured one with vsync (NaN if none: a paced session's rate is the clock's,
    not the display's); on a tie, the first."""
    rates = [(len(r.ratings), -k, float(d["refresh_hz"]))
             for k, (r, d) in enumerate((r, r.info.display or {}) for r in recs)
             if isinstance(d.get("refresh_hz"), int | float) and d.get("vsync") is True]
    return max(rates)[2] if rates else float("nan")


def _card_geometry(recs: list) -> dict[str, Any]:
    """The geometry the vision screening's card calibration measured ({} if none)."""
    for r in reversed(recs):
        for s in reversed(r.screenings):
            geometry = (s.get("result") or {}).get("geometry") or {}
            if all(isinstance(geometry.get(k), int | float) for k in GEOMETRY_KEYS):
                return geometry
    return {}


def _seating_cm(recs: list) -> float:
    """The distance the session told the participant to sit at while rating (NaN if none)."""
    for r in reversed(recs):
        cm = ((r.info.settings or {}).get("protocol") or {}).get("viewing_distance_cm")
        if isinstance(cm, int | float):
            return float(cm)
    return float("nan")


def display_facts(recs: list) -> dict[str, Any]:
    """Screen, refresh rate, seating distance, and the pixel density and pixels per degree
    (at the seating distance) where the card calibration measured them."""
    geometry = _card_geometry(recs)
    seat = _seating_cm(recs)
    ppd = float("nan")
    if geometry and np.isfinite(seat):  # px per degree grows with the distance
        ppd = geometry["px_per_degree"] * seat / geometry["viewing_distance_cm"]
    return {"screen": _screens(recs), "refresh_hz": _refresh_hz(recs),
            "viewing_distance_cm": seat, "px_per_mm": geometry.get("px_per_mm", float("nan")),
            "px_per_degree": ppd}
