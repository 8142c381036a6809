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
REMIND_STOPPED_AFTER_S = 24 * 3600
"""A participant who chose "stop and continue later" is marked only once this long has passed
without them coming back: a reminder the same day nags someone who said they would return."""
CAME_BACK_S = 5 * 60
"""A stopped participant whose app reached the server this long after the last upload came
back (it fetched the study again) but sent nothing: their display check failed, or they
closed the app before it."""


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


def _later_by(iso: str | None, than: str | None, seconds: float) -> bool:
    """``iso`` is more than ``seconds`` after ``than`` (both known)."""
    t, t0 = parse_time(iso), parse_time(than)
    return t is not None and t0 is not None and (t - t0).total_seconds() > seconds


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


LOOK_NOW, LOOK, REMIND = 3, 2, 1
"""How much a reason to look at a participant matters: their data may be unusable or they
need help (``LOOK_NOW``), a mark on the data (``LOOK``), a reminder or a wait (``REMIND``).
The "those to look at first" order sorts by it, then by the number of reasons."""

FLAG_WORDS = {
    "second_session": "a second session",
    "local_edit": "session file edited on the computer",
    "contradiction": "an upload contradicted what had arrived",
    "refused": "an upload refused, nothing accepted since",
}
"""The upload flags in the "participants to look at" list, in words (the flags table below
the list gives each flag's full message)."""
FLAG_URGENCY = {"second_session": LOOK_NOW, "local_edit": LOOK_NOW, "contradiction": LOOK_NOW,
                "refused": LOOK}
"""How much each upload flag needs a look (a kind not named here: ``LOOK``)."""
HANDLED_FLAGS = frozenset({"offline_gap", "clock_skew"})
"""Facts the server already handled (answers that arrived late after rating offline, a
clock it corrected): in the flags table and the row's flags cell, not in the list."""


def reasons(row: dict[str, Any], partial: bool, limits: CellLimits) -> list[tuple[int, str]]:
    """Why one participant's row needs a look: (urgency, words) for the cells the table
    marks (with the report's thresholds, ``limits``), their state and their flags. Empty for
    a participant who withdrew in the app (nothing of theirs is used)."""
    if row["state"] == "withdrew in app":
        return []
    ps, out = row["ps"], []
    seen = _ago(row["p"]["last_seen"])
    if row.get("came_back"):
        out.append((LOOK_NOW, f"came back {seen} but sent nothing since: the display check "
                              "may have failed, ask them"))
    elif row["stalled"] and row["state"] == FETCHED:
        out.append((LOOK_NOW, f"got the study {seen} but no session arrived: the display "
                              "check may have failed, ask them"))
    elif row["stalled"] and row["state"] == STOPPED:
        out.append((REMIND, f"stopped {seen}, not back since"))
    elif row["stalled"]:
        out.append((REMIND, f"no contact for {seen.replace(' ago', '')}"))
    if ps is not None:
        if ps.removed_by_screening:
            out.append((LOOK_NOW, "screening would remove"))
        elif partial:
            out.append((REMIND, "partial: not used yet"))
        failed = [t for t, o in sorted(ps.vision.items()) if o == "failed"]
        if failed:
            out.append((LOOK_NOW, f"failed the {', '.join(failed)} check"))
        if ps.panel_r is not None and ps.panel_r < limits.panel_r:
            out.append((LOOK, f"r panel {ps.panel_r:.2f}"))
        if limits.hidden_reference_low(ps.hidden_reference_mean):
            out.append((LOOK, f"hidden references rated {ps.hidden_reference_mean:.1f} on "
                              "average"))
        if ps.timing and ps.timing not in ("vsync", "simulated"):
            out.append((LOOK_NOW, f"timing {ps.timing}"))
        if ps.dropped_frames:
            out.append((LOOK, f"{ps.dropped_frames} dropped frame(s)"))
        if ps.requeued:
            out.append((LOOK, f"{ps.requeued} re-queued trial(s)"))
        if ps.preflight_skipped and not ps.simulated:  # a simulated rater has no display
            out.append((LOOK_NOW, "pre-flight skipped"))
        if ps.preflight_failed:
            out.append((LOOK_NOW, f"pre-flight: {', '.join(ps.preflight_failed)} failed"))
        if ps.unreadable:
            out.append((LOOK_NOW, f"{ps.unreadable} unreadable "
                                  f"entr{'y' if ps.unreadable == 1 else 'ies'}"))
    last_received = parse_time((row.get("s") or {}).get("last_received"))
    for f in row["p"]["flags"]:
        if f["kind"] in HANDLED_FLAGS:
            continue
        urgency = FLAG_URGENCY.get(f["kind"], LOOK)
        if f["kind"] == "refused" and last_received is not None and \
                (parse_time(f["last_at"]) or last_received) < last_received:
            continue  # later uploads were accepted: the app sent the batch again, as it does
        words = FLAG_WORDS.get(f["kind"], f["kind"].replace("_", " "))
        out.append((urgency, words + (f" ×{f['count']}" if f["count"] > 1 else "")))
    return out


def attention(row: dict[str, Any], partial: bool, limits: CellLimits) -> list[str]:
    """:func:`reasons` in words, as the "participants to look at" list gives them."""
    return [words for _, words in reasons(row, partial, limits)]


ORDERS = ("id", "look")


def _to_go(rows: list[dict[str, Any]], per_participant: int) -> dict[str, tuple[int, int]]:
    """The ratings still to come, by who owes them: (ratings, participants) for those
    rating now, those who stopped or went quiet, and those who have not started. Only the
    first are on their way; the estimate of the time to completion assumes all of them."""
    out = {"rating now": [0, 0], "stopped": [0, 0], "not started": [0, 0]}
    for r in rows:
        s = r["s"]
        if r["state"] in ("finished", "withdrew in app") or (s and s.get("finished_at")):
            continue
        if s is None:
            n, who = per_participant, "not started"
        else:
            n = max(r["planned"] - s["n_ratings"], 0)
            who = "rating now" if r["state"] == "running" and not r["stalled"] else "stopped"
        if n:
            out[who][0] += n
            out[who][1] += 1
    return {k: (n, people) for k, (n, people) in out.items()}


def _to_go_words(to_go: dict[str, tuple[int, int]]) -> str:
    """ "14 from the 2 participants rating now, 64 from 5 who stopped or went quiet, 120 from
    10 not started" (a bare "the 1 rating now" read as one rating)."""
    words = {"rating now": "the {p} {participants} rating now",
             "stopped": "{p} who stopped or went quiet", "not started": "{p} not started"}
    return ", ".join(f"{n} from " + words[who].format(
        p=people, participants="participant" if people == 1 else "participants")
        for who, (n, people) in to_go.items() if n)


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
                         "stalled": _older_than(p["last_seen"], {
                             "running": STALLED_AFTER_S, FETCHED: STALLED_AFTER_S,
                             STOPPED: REMIND_STOPPED_AFTER_S}.get(state, math.inf)),
                         "came_back": state == STOPPED and _later_by(
                             p["last_seen"], s["last_received"], CAME_BACK_S)})
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
        to_go_by = _to_go(rows, snap.planned_per_participant)
        to_go = sum(n for n, _ in to_go_by.values())
        partial = set(snap.study.partial) if snap.study is not None else set()
        for r in rows:
            why = reasons(r, r["p"]["participant"] in partial, snap.limits)
            r["attention"] = [words for _, words in why]
            r["urgency"] = max((u for u, _ in why), default=0)
        if order == "look":  # the most urgent first, then the most reasons (stable)
            rows.sort(key=lambda r: (-r["urgency"], -len(r["attention"])))
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
            "to_go_words": _to_go_words(to_go_by), "n_versions": len(listing["versions"]),
            "n_arrived_withdrawn": arrived_withdrawn, "n_pending": pending,
            "n_withdrew_in_app": len(left),
            "withdrew_in_app": [r["p"]["participant"] for r in left],
            "n_withdrawn": len(listing["withdrawn"]) + len(left),
            "rate_per_hour": rate, "eta_hours": to_go / rate if rate > 0 else None,
            "versions": {v["manifest_sha256"]: v["version"] for v in listing["versions"]},
            "order": order,
        }

    def dashboard(self, order: str = "id") -> str:
        return self.env.get_template("dashboard.html").render(**self.context(order))
