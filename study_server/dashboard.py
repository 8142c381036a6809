"""The dashboard's pages, rendered on the server (Jinja2, autoescaped).

Live facts (progress, last seen, flags) are read from the database per request, which is
cheap; everything statistical comes from the last background snapshot and is shown with its
age. Times are stored in UTC; the page shows them in the browser's local time (a few lines
of plain JavaScript, which also reloads the page), or in UTC without JavaScript.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from jinja2 import Environment, FileSystemLoader, select_autoescape

from session_store.records import utc_now

from .ingest import parse_time

if TYPE_CHECKING:
    from collections.abc import Callable

    from .stats import CellLimits, StatsWorker

TEMPLATES = Path(__file__).parent / "templates"
REFRESH_S = 30
STALLED_AFTER_S = 15 * 60
"""A running participant not heard from for this long is marked: their app is closed or
cannot reach the server, and a reminder may help."""


def _ago(iso: str | None) -> str:
    t = parse_time(iso)
    if t is None:
        return "never"
    s = (datetime.now(UTC) - t).total_seconds()
    if s < 90:
        return f"{max(s, 0):.0f} s ago"
    if s < 5400:
        return f"{s / 60:.0f} min ago"
    if s < 48 * 3600:
        return f"{s / 3600:.1f} h ago"
    return f"{s / 86400:.1f} days ago"


def _older_than(iso: str | None, seconds: float) -> bool:
    t = parse_time(iso)
    return t is not None and (datetime.now(UTC) - t).total_seconds() > seconds


def _fmt(x: Any, digits: int = 1) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{digits}f}"


def _duration(hours: float | None) -> str:
    if hours is None or not math.isfinite(hours):
        return "–"
    minutes = hours * 60
    if minutes < 1:
        return "< 1 min"
    if minutes < 90:
        return f"{minutes:.0f} min"
    if hours < 48:
        return f"{hours:.1f} h"
    return f"{hours / 24:.1f} days"


FETCHED = "seen, no session yet"
"""A participant whose app reached the server (the study fetched, files downloaded, a
handshake) but whose session has not: still downloading, stuck, stopped at the pre-flight,
or reading the consent. "last seen" says when."""


STOPPED = "stopped, to continue later"
"""A participant who chose "stop and continue later" on the pause screen: the last thing
their app sent; they come back with the same invitation."""


def attention(row: dict[str, Any], partial: bool, limits: CellLimits) -> list[str]:
    """Why one participant's row needs a look, in words: the cells the table marks (with the
    report's thresholds, ``limits``), plus their flags. Empty for a participant who withdrew
    in the app (nothing of theirs is used)."""
    if row["state"] == "withdrew in app":
        return []
    ps, out = row["ps"], []
    if row["stalled"]:
        out.append(f"no contact for {_ago(row['p']['last_seen']).replace(' ago', '')}")
    if ps is not None:
        if ps.removed_by_screening:
            out.append("screening would remove")
        elif partial:
            out.append("partial: not used yet")
        failed = [t for t, o in sorted(ps.vision.items()) if o == "failed"]
        if failed:
            out.append(f"failed the {', '.join(failed)} check")
        if ps.panel_r is not None and ps.panel_r < limits.panel_r:
            out.append(f"r panel {ps.panel_r:.2f}")
        if limits.hidden_reference_low(ps.hidden_reference_mean):
            out.append(f"hidden references rated {ps.hidden_reference_mean:.1f} on average")
        if ps.timing and ps.timing not in ("vsync", "simulated"):
            out.append(f"timing {ps.timing}")
        if ps.dropped_frames:
            out.append(f"{ps.dropped_frames} dropped frame(s)")
        if ps.requeued:
            out.append(f"{ps.requeued} re-queued trial(s)")
        if ps.preflight_skipped and not ps.simulated:  # a simulated rater has no display
            out.append("pre-flight skipped")
        if ps.preflight_failed:
            out.append(f"pre-flight: {', '.join(ps.preflight_failed)} failed")
        if ps.unreadable:
            out.append(f"{ps.unreadable} unreadable entr{'y' if ps.unreadable == 1 else 'ies'}")
    for f in row["p"]["flags"]:
        words = FLAG_WORDS.get(f["kind"], f["kind"].replace("_", " "))
        out.append(words + (f" ×{f['count']}" if f["count"] > 1 else ""))
    return out


FLAG_WORDS = {
    "offline_gap": "answers arrived late (offline meanwhile)",
    "clock_skew": "computer clock far off",
    "second_session": "a second session",
    "local_edit": "session file edited on the computer",
    "contradiction": "an upload contradicted what had arrived",
    "refused": "an upload refused",
}
"""The upload flags in the "participants to look at" list, in words (the flags table below
the list gives each flag's full message)."""


ORDERS = ("id", "look")


class Pages:
    """The login and dashboard pages, from the session listing and the latest statistics."""

    def __init__(self, study_id: str, stats: StatsWorker,
                 sessions_listing: Callable[[], dict[str, Any]], stats_every_s: float) -> None:
        self.study_id = study_id
        self.stats = stats
        self.sessions_listing = sessions_listing
        self.stats_every_s = stats_every_s
        self.env = Environment(loader=FileSystemLoader(TEMPLATES),
                               autoescape=select_autoescape(["html"]), trim_blocks=True,
                               lstrip_blocks=True)
        self.env.filters["ago"] = _ago
        self.env.filters["fmt"] = _fmt
        self.env.filters["duration"] = _duration

    def login(self, message: str | None = None) -> str:
        return self.env.get_template("login.html").render(
            study_id=self.study_id, message=message)

    def context(self, order: str = "id") -> dict[str, Any]:
        """The page's data; ``order`` "look" puts the participants to look at first."""
        listing = self.sessions_listing()
        snap = self.stats.snapshot()
        rows = []
        for p in listing["participants"]:
            s = p["session"]
            ps = snap.participants.get(p["participant"])
            state = "invited" if not p["last_seen"] else FETCHED
            if s is not None:
                state = {"finish": "finished", "withdrawn": "withdrew in app"}.get(
                    s["closed_as"] or "", STOPPED if s.get("stopped") else "running")
            planned = 0
            if s is not None:  # an adaptive session plans its later blocks as it goes
                planned = s["n_planned"] if s["finished_at"] else \
                    max(s["n_planned"], snap.planned_per_participant)
            rows.append({"p": p, "s": s, "ps": ps, "state": state, "planned": planned,
                         "progress": (s["n_ratings"] / planned) if s and planned else 0.0,
                         "stalled": state in ("running", STOPPED, FETCHED) and _older_than(
                             p["last_seen"], STALLED_AFTER_S)})
        per_stim = sorted(snap.per_stimulus.items(), key=lambda kv: kv[1])
        counts = [n for _, n in per_stim]
        scenes = None
        if snap.study is not None and snap.study.dmos is not None:
            d = snap.study.dmos
            d = d[~d["is_hidden_reference"]]
            scenes = [(scene, g.to_dict("records")) for scene, g in d.groupby("scene", sort=True)]
        flags = [(p["participant"], f) for p in listing["participants"] for f in p["flags"]]
        flags.sort(key=lambda pf: pf[1]["last_at"], reverse=True)
        started = sum(1 for r in rows if r["s"] is not None)
        left = [r for r in rows if r["state"] == "withdrew in app"]
        arrived = sum(r["s"]["n_ratings"] for r in rows
                      if r["s"] is not None and r not in left)
        arrived_withdrawn = sum(r["s"]["n_ratings"] for r in left)
        current = {v["manifest_sha256"] for v in listing["versions"] if v["current"]}
        arrived_earlier = sum(r["s"]["n_ratings"] for r in rows
                              if r["s"] is not None and r["s"]["manifest_sha256"] not in current)
        to_go = sum((snap.planned_per_participant if r["s"] is None else
                     0 if r["s"]["finished_at"] else
                     max(r["planned"] - r["s"]["n_ratings"], 0)) for r in rows)
        partial = set(snap.study.partial) if snap.study is not None else set()
        for r in rows:
            r["attention"] = attention(r, r["p"]["participant"] in partial, snap.limits)
        if order == "look":  # the rows to look at first, the most reasons first (stable)
            rows.sort(key=lambda r: -len(r["attention"]))
        finished = sum(1 for r in rows if r["state"] == "finished")
        pending = sum(1 for r in rows if r["state"] in ("invited", FETCHED, "running",
                                                        STOPPED))
        rate = self.stats.rate_per_hour()
        return {
            "study_id": self.study_id, "listing": listing, "rows": rows, "snap": snap,
            "age": snap.age_s(), "now": utc_now(), "refresh": REFRESH_S,
            "stats_every": self.stats_every_s,
            "per_stim_low": per_stim[:12], "per_stim_min": min(counts, default=0),
            "per_stim_median": sorted(counts)[len(counts) // 2] if counts else 0,
            "per_stim_max": max(counts, default=0),
            "below_target": sum(1 for n in counts if n < snap.target_per_stimulus),
            "n_stimuli": len(counts), "scenes": scenes, "flags": flags,
            "attention": [r for r in rows if r["attention"]], "limits": snap.limits,
            "n_invited": len(rows), "n_started": started, "n_finished": finished,
            "n_arrived": arrived, "n_arrived_earlier": arrived_earlier, "n_to_go": to_go,
            "n_arrived_withdrawn": arrived_withdrawn, "n_pending": pending,
            "n_withdrew_in_app": len(left),
            "n_withdrawn": len(listing["withdrawn"]) + len(left),
            "rate_per_hour": rate, "eta_hours": to_go / rate if rate > 0 else None,
            "versions": {v["manifest_sha256"]: v["version"] for v in listing["versions"]},
            "order": order,
        }

    def dashboard(self, order: str = "id") -> str:
        return self.env.get_template("dashboard.html").render(**self.context(order))
