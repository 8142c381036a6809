"""How long a participant spent in the study: the time from each start of a session (a new
session or a return to it) to the last thing recorded before the next start, summed. A pause
within a sitting counts; the days between stopping and coming back do not."""

from __future__ import annotations

from datetime import datetime
from typing import Any


def _time(stamp: Any) -> datetime | None:
    if not isinstance(stamp, str) or not stamp:
        return None
    try:
        return datetime.fromisoformat(stamp.replace("Z", "+00:00"))
    except ValueError:
        return None


def sittings(rec: Any) -> list[float]:
    """The minutes of each sitting of one session (empty when it never started)."""
    starts = sorted(t for e in rec.events if e.get("kind") == "start"
                    and (t := _time(e.get("at"))) is not None)
    if not starts:
        return []
    stamps = [_time(e.get("at")) for e in rec.events]
    stamps += [_time(p.get("answered_at")) for p in rec.presentations]
    stamps += [_time(r.get("presented_at")) for r in rec.ratings]
    known = sorted(t for t in stamps if t is not None)
    out = []
    for k, start in enumerate(starts):
        end = starts[k + 1] if k + 1 < len(starts) else None
        inside = [t for t in known if t >= start and (end is None or t < end)]
        out.append((max(inside) - start).total_seconds() / 60 if inside else 0.0)
    return out


def study_minutes(recs: list) -> tuple[float, int]:
    """(minutes over every sitting of every session, number of sittings) of one participant;
    NaN minutes when no session started."""
    spans = [m for rec in recs for m in sittings(rec)]
    return (float(sum(spans)) if spans else float("nan")), len(spans)
