"""Minutes in the study: each sitting from its start to the last thing recorded before the
next start, summed; the days away between sittings do not count."""

from __future__ import annotations

import math
from types import SimpleNamespace

from analysis.session_time import sittings, study_minutes


def _rec(events, presentations=(), ratings=()):
    return SimpleNamespace(events=[{"kind": k, "at": at} for k, at in events],
                           presentations=list(presentations), ratings=list(ratings))


def test_sittings_are_summed_without_the_time_away():
    rec = _rec([("created", "2026-01-01T10:00:00.000Z"), ("start", "2026-01-01T10:00:30.000Z"),
                ("quit", "2026-01-01T10:07:30.000Z"),
                ("start", "2026-01-03T09:00:00.000Z"), ("finish", "2026-01-03T09:04:00.000Z")],
               presentations=[{"answered_at": "2026-01-01T10:05:00.000Z"},
                              {"answered_at": "2026-01-03T09:03:00.000Z"}])
    assert sittings(rec) == [7.0, 4.0]
    # a sitting that ended in a crash ends at its last answer
    crashed = _rec([("start", "2026-01-01T10:00:00Z"), ("start", "2026-01-01T12:00:00Z"),
                    ("finish", "2026-01-01T12:01:00Z")],
                   ratings=[{"presented_at": "2026-01-01T10:02:30Z"}])
    assert sittings(crashed) == [2.5, 1.0]
    assert study_minutes([rec, crashed]) == (14.5, 4)


def test_a_session_that_never_started_has_no_time():
    minutes, n = study_minutes([_rec([("created", "2026-01-01T10:00:00Z")])])
    assert math.isnan(minutes) and n == 0


def test_an_implausible_time_in_the_study_is_flagged():
    import pandas as pd

    from analysis.quality import rater_flags

    assert not any("h in the study" in f for f in rater_flags(pd.Series({"minutes": 35.0}),
                                                                None))
    flags = rater_flags(pd.Series({"minutes": 388462.4}), None)
    assert "6474 h in the study (> 12 h: a computer clock that jumped during a sitting?)" \
        in flags
