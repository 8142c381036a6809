"""The data-quality section: what each participant did, and what looks wrong.

Facts come from the session files (settings, display, pre-flight, presentation logs) or, for a
ratings CSV, from the columns it has. Agreement figures come from the ratings (correlation
with the leave-one-out panel mean, repeat correlation) and from the screening. Each flag names
its threshold (:data:`THRESHOLDS`), so the report can say why a rater is flagged; flags inform,
the screening rule (:mod:`analysis.screening`) and ``--min-completeness`` decide.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from session_store.mutations import BLOCK_EVENT

from .data import Exclusion, RatingSet, balanced_subset, drop_unrated, rater_order
from .display_facts import display_facts
from .errors import AnalysisError
from .reliability import repetition_correlation
from .session_protocol import session_protocol
from .session_time import study_minutes
from .thresholds import THRESHOLDS

LONG_MINUTES = 12 * 60
"""A participant longer in the study than this (away time between sittings not counted) had
a clock that jumped, or left the app open overnight: flagged, the time is not believed."""

FACT_COLUMNS = ("sessions", "files", "n_ratings", "n_planned", "completeness", "timing_mode",
                "blocks_planned_by", "vsync", "preflight_skipped", "finished", "presentations",
                "dropped_frames", "trials_with_drops", "requeued", "median_viewing_s",
                "median_toggles", "minutes", "sittings", "screen", "refresh_hz",
                "viewing_distance_cm", "px_per_mm", "px_per_degree", "practice_trials",
                "break_every")


def _median(values: Iterable[Any]) -> float:
    arr = np.array([float(v) for v in values if v is not None and np.isfinite(float(v))])
    return float(np.median(arr)) if arr.size else float("nan")


def _viewing_ms(p: dict[str, Any]) -> float | None:
    if p.get("viewing_ms") is not None:
        return float(p["viewing_ms"])
    parts = [p.get("ms_on_reference"), p.get("ms_on_test")]
    if all(v is None for v in parts):
        return None
    return float(sum(float(v or 0.0) for v in parts))


def _toggles(p: dict[str, Any]) -> float | None:
    if p.get("n_toggles") is not None:
        return float(p["n_toggles"])
    times = p.get("toggle_times_ms")
    return float(len(times)) if isinstance(times, list) else None


def facts_from_sessions(records: list) -> pd.DataFrame:
    """One row per participant from their session records (see :mod:`analysis.sessions`)."""
    rows = []
    by_participant: dict[str, list] = {}
    for rec in records:
        by_participant.setdefault(rec.info.participant, []).append(rec)
    for participant, recs in by_participant.items():
        pres = [p for r in recs for p in r.presentations]
        if not pres:  # reader without presentation logs: the rating rows carry the basics
            pres = [dict(row, outcome="rated") for r in recs for row in r.ratings]
        rated = [p for p in pres if p.get("outcome", "rated") == "rated"]
        drops = [int(p.get("dropped_frames") or 0) for p in pres]
        vsync = [r.vsync for r in recs if r.vsync is not None]
        modes = sorted({r.timing_mode for r in recs if r.timing_mode})
        planners = sorted({str(e.get("issued_by")) for r in recs for e in r.events
                           if e.get("kind") == BLOCK_EVENT and e.get("issued_by")})
        rows.append({
            "rater": participant,
            "sessions": len(recs),
            "files": "; ".join(r.name or r.path for r in recs),
            "n_planned": max(r.n_planned for r in recs),
            "timing_mode": ", ".join(modes),
            "blocks_planned_by": ", ".join(planners),
            "vsync": (all(vsync) if vsync else None),
            "preflight_skipped": any(r.info.preflight_skipped for r in recs),
            "finished": all(r.info.finished_at is not None for r in recs),
            "altered": "; ".join(r.altered for r in recs if r.altered),
            "presentations": len(pres),
            "dropped_frames": int(sum(drops)),
            "trials_with_drops": int(sum(d > 0 for d in drops)),
            "requeued": int(sum(p.get("outcome") == "requeued" for p in pres)),
            "median_viewing_s": _median(_viewing_ms(p) for p in rated) / 1000.0,
            "median_toggles": _median(_toggles(p) for p in rated),
            **dict(zip(("minutes", "sittings"), study_minutes(recs), strict=True)),
            **display_facts(recs),
            **session_protocol(recs),
        })
    return pd.DataFrame(rows).set_index("rater") if rows else pd.DataFrame()


def facts_from_rows(frame: pd.DataFrame) -> pd.DataFrame:
    """One row per participant from tidy rating rows (the columns a CSV has)."""
    if frame.empty:
        return pd.DataFrame()
    out = pd.DataFrame(index=pd.Index(rater_order(frame["participant"]),
                                      name="rater"))
    g = frame.assign(participant=frame["participant"].astype(str)).groupby("participant")
    out["presentations"] = g.size()
    if "dropped_frames" in frame.columns:
        d = pd.to_numeric(frame["dropped_frames"], errors="coerce").fillna(0)
        out["dropped_frames"] = d.groupby(frame["participant"].astype(str)).sum().astype(int)
        out["trials_with_drops"] = (d > 0).groupby(frame["participant"].astype(str)).sum() \
            .astype(int)
    if {"ms_on_reference", "ms_on_test"} <= set(frame.columns):
        v = pd.to_numeric(frame["ms_on_reference"], errors="coerce").fillna(0) + \
            pd.to_numeric(frame["ms_on_test"], errors="coerce").fillna(0)
        out["median_viewing_s"] = v.groupby(frame["participant"].astype(str)).median() / 1000
    if "n_toggles" in frame.columns:
        t = pd.to_numeric(frame["n_toggles"], errors="coerce")
        out["median_toggles"] = t.groupby(frame["participant"].astype(str)).median()
    if "session" in frame.columns:
        out["sessions"] = g["session"].nunique()
    return out


# -- agreement figures ------------------------------------------------------------------
MIN_PANEL_STIMULI = 5
"""Fewest stimuli a rater's panel correlation is computed from. Below five, the 95 % interval
of a Pearson r spans most of [-1, 1] whatever the rater did, so the number would only
alarm or reassure by chance."""


def loo_correlation(means: np.ndarray, min_stimuli: int = MIN_PANEL_STIMULI) -> np.ndarray:
    """Per rater, Pearson r between their ratings and the mean of all other raters (over the
    stimuli they rated and someone else rated too). NaN with fewer than ``min_stimuli``
    stimuli or no variance (a rater who gives one value to everything)."""
    n_raters = means.shape[1]
    finite = np.isfinite(means)
    x = np.where(finite, means, 0.0)
    total, count = x.sum(axis=1), finite.sum(axis=1)
    out = np.full(n_raters, np.nan)
    for s in range(n_raters):
        others_n = count - finite[:, s]
        with np.errstate(invalid="ignore", divide="ignore"):
            others = (total - x[:, s]) / others_n
        ok = finite[:, s] & (others_n > 0)
        if ok.sum() < min_stimuli:
            continue
        a, b = means[ok, s], others[ok]
        if a.std() > 0 and b.std() > 0:
            out[s] = float(np.corrcoef(a, b)[0, 1])
    return out


def panel_correlation(rs: RatingSet) -> pd.Series:
    """Per rater, the leave-one-out panel correlation of their per-stimulus mean ratings:
    the one definition that the report's data-quality table and the live dashboard show.
    In an unbalanced design, on the first rating per stimulus (as the screening's r1)."""
    sub, _ = balanced_subset(rs)
    return pd.Series(loo_correlation(sub.rater_means()), index=rs.raters, dtype=float)


def hidden_reference_mean(rs: RatingSet) -> np.ndarray:
    """Per rater, the mean rating given to hidden references (NaN: none rated)."""
    hidden = rs.hidden_reference_mask
    if not hidden.any():
        return np.full(rs.n_raters, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(rs.scores[hidden].transpose(1, 0, 2).reshape(rs.n_raters, -1),
                          axis=1)


def quality_table(rs: RatingSet, *, screening: pd.DataFrame | None = None,
                  repeat_r: np.ndarray | None = None,
                  min_completeness: float | None = None) -> pd.DataFrame:
    """The per-rater data-quality table: facts, agreement, screening figures and flags.

    Raters left out before the analysis (partial sessions below ``min_completeness``) keep
    their row with status ``dropped``; ``screening`` (indexed by rater) adds the screening
    statistics and the decision.
    """
    info = rs.rater_info.copy() if rs.rater_info is not None else pd.DataFrame(
        index=pd.Index(rs.raters, name="rater"))
    for col in FACT_COLUMNS:
        if col not in info.columns:
            info[col] = np.nan
    info = info.reindex(list(dict.fromkeys([*info.index, *rs.raters])))
    if "status" not in info.columns:
        info["status"] = "used"
    info["status"] = info["status"].fillna("used")
    loo = panel_correlation(rs)
    rep = pd.Series(repeat_r if repeat_r is not None else repetition_correlation(rs.scores),
                    index=rs.raters)
    span = rs.scale_max - rs.scale_min
    hid = pd.Series((hidden_reference_mean(rs) - rs.scale_min) / span, index=rs.raters)
    info["hidden_ref_mean_share"] = hid
    info["loo_r"] = loo
    info["repeat_r"] = rep
    if screening is not None:
        for col in screening.columns:
            info[f"screen_{col}"] = screening[col]
    modes = info["timing_mode"].astype(str) if "timing_mode" in info.columns else \
        pd.Series("", index=info.index)
    simulated = modes.str.contains("simulated")
    mixed = bool(simulated.any() and not simulated.all())
    vision = _vision_flags(rs)
    info["flags"] = ["; ".join(rater_flags(row, min_completeness, simulated_among_real=mixed)
                               + vision.get(str(rater), []))
                     for rater, row in info.iterrows()]
    info.index.name = "rater"
    return info


def _vision_flags(rs: RatingSet) -> dict[str, list[str]]:
    """Per rater, the vision checks of the study's panel that they failed or that were
    inconclusive (flags, not exclusions: --exclude-failed-vision leaves the failed out)."""
    if rs.panel is None:
        return {}
    out: dict[str, list[str]] = {}
    for rater, checks in rs.panel.screenings.items():
        for test, outcome in sorted(checks.items()):
            if outcome in ("failed", "inconclusive"):
                out.setdefault(str(rater), []).append(f"{test} check {outcome} (vision "
                                                      "screening)")
    return out


def rater_flags(row: pd.Series, min_completeness: float | None, *,
                simulated_among_real: bool = False) -> list[str]:
    """The flags of one row of the quality table, each naming its threshold.
    ``simulated_among_real``: the panel mixes simulated and real sessions, so a simulated
    rater is flagged as one (in an all-simulated dry run that would flag everyone)."""
    t = THRESHOLDS
    out = []
    c = row.get("completeness")
    if c is not None and np.isfinite(c):
        if min_completeness is not None and c < min_completeness:
            out.append(f"completeness {c:.0%} < {min_completeness:.0%} (dropped)")
        elif c < t["completeness"]:
            out.append(f"completeness {c:.0%} < {t['completeness']:.0%}")
    if row.get("vsync") is False:
        out.append("vsync off")
    if simulated_among_real and "simulated" in str(row.get("timing_mode") or ""):
        out.append("simulated rater (cgvq-study simulate; not a person)")
    if row.get("timing_mode") and "paced" in str(row.get("timing_mode")):
        out.append(f"timing mode {row['timing_mode']} (no vsync; pilot only)")
    if row.get("preflight_skipped") is True and "simulated" not in str(row.get("timing_mode")):
        out.append("pre-flight skipped")  # a simulated rater has no display to check
    pres, drops = row.get("presentations"), row.get("trials_with_drops")
    if pres and drops is not None and np.isfinite(drops) and pres > 0 and \
            drops / pres > t["dropped_trials"]:
        out.append(f"dropped frames in {drops / pres:.0%} of presentations "
                   f"(> {t['dropped_trials']:.0%})")
    req = row.get("requeued")
    if req is not None and np.isfinite(req) and req > 0:
        out.append(f"{int(req)} trial(s) re-queued")
    v = row.get("median_viewing_s")
    if v is not None and np.isfinite(v) and v < t["viewing_s"]:
        out.append(f"median viewing {v:.2f} s < {t['viewing_s']:g} s")
    h = row.get("hidden_ref_mean_share")
    if h is not None and np.isfinite(h) and h < t["hidden_reference"]:
        out.append(f"hidden references rated at {h:.0%} of the scale on average "
                   f"(< {t['hidden_reference']:.0%})")
    r = row.get("loo_r")
    if r is not None and np.isfinite(r) and r < t["loo_r"]:
        out.append(f"r with all others {r:.2f} < {t['loo_r']}")
    elif row.get("status") == "used" and r is not None and not np.isfinite(r):
        out.append("no agreement figure (too few ratings or no variance)")
    rr = row.get("repeat_r")
    if rr is not None and np.isfinite(rr) and rr < t["repeat_r"]:
        out.append(f"repeat r {rr:.2f} < {t['repeat_r']}")
    m = row.get("minutes")
    if m is not None and np.isfinite(m) and m > LONG_MINUTES:
        out.append(f"{m / 60:.0f} h in the study (> {LONG_MINUTES // 60} h: a computer clock "
                   "that jumped during a sitting?)")
    return out


ALTERED_SESSION = "altered session"
"""The exclusion of a rater whose session file was changed outside the app, leaving too few
authentic ratings (before the change) to pass the completeness rule."""


def altered_at(rs: RatingSet, rater: str) -> str:
    """Where ``rater``'s session file fails its integrity check, in words ('' if intact)."""
    info = rs.rater_info
    if info is None or "altered" not in info.columns or rater not in info.index:
        return ""
    value = info.loc[rater, "altered"]
    return value if isinstance(value, str) else ""


def drop_incomplete(rs: RatingSet, min_completeness: float) -> RatingSet:
    """Leave out raters whose completeness is below ``min_completeness`` (0 keeps everyone).

    Each one becomes an :class:`~analysis.data.Exclusion`; stimuli that only they rated are
    left out too (reported as an input problem).
    """
    comp = rs.completeness()
    drop = [k for k, c in enumerate(comp) if np.isfinite(c) and c < min_completeness]
    if not drop:
        return rs
    info = rs.rater_info.copy() if rs.rater_info is not None else None
    exclusions = list(rs.exclusions)
    for k in drop:
        rater = rs.raters[k]
        n = planned = None
        altered = altered_at(rs, rater)
        if info is not None and rater in info.index:
            n, planned = info.loc[rater, "n_ratings"], info.loc[rater, "n_planned"]
            info.loc[rater, "status"] = "dropped (altered file)" if altered else \
                "dropped (partial)"
        done = f"{int(n)} of {int(planned)} planned trials" if n is not None and \
            np.isfinite(planned) else "part of the stimuli"
        below = f"({comp[k]:.0%}), below --min-completeness {min_completeness:.0%}"
        exclusions.append(Exclusion(
            ALTERED_SESSION, rater,
            f"session file altered outside the app ({altered}): only the ratings before the "
            f"change are authentic, {done} {below}",
            f"--min-completeness {min_completeness:g} on the authentic ratings")
            if altered else Exclusion(
            "partial rater", rater, f"answered {done} {below}",
            f"--min-completeness {min_completeness:g}"))
    keep = [k for k in range(rs.n_raters) if k not in drop]
    if len(keep) < 2:
        raise AnalysisError(
            f"only {len(keep)} rater(s) reach --min-completeness {min_completeness:g}; lower it "
            "(e.g. --min-completeness 0) to analyse partial sessions (completeness is ratings "
            "given / trials planned; from a ratings CSV the plan is the manifest's stimuli x "
            "protocol.repetitions)")
    out = rs.with_raters(keep)
    out = replace(out, exclusions=exclusions, rater_info=info)
    return drop_unrated(out, "completeness",
                        f"their raters are below --min-completeness {min_completeness:g}")
