"""A pilot's ratings by distortion level: what one or a few people's run of a study says
about the study's levels before anyone is invited.

DMOS, reliability and screening need a panel; a pilot answers other questions. Do the
ratings fall from the mildest level to the strongest (the lowest level, level 1 by
convention, is the strongest: ratings that fall from it to the mildest mean the levels are
numbered the wrong way round)? Is the strongest level visible at all, and does the mildest
come near the reference? Did the raters use the scale? The
differential score of a test video is its hidden reference's rating minus its own (the
same rater, averaged over repetitions): 0 where the distortion went unseen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .data import RatingSet

FLAT_SHARE = 0.05
"""Mean ratings of the strongest and mildest level closer than this share of the scale: the
ratings do not follow the level (further apart the wrong way: the levels are reversed)."""
UNSEEN_SHARE = 0.10
"""The strongest level rated less than this share of the scale below its reference."""
NO_THRESHOLD_SHARE = 0.30
"""The mildest level rated more than this share of the scale below its reference."""
NARROW_SHARE = 0.40
"""A rater whose ratings span less than this share of the scale."""


@dataclass
class PilotView:
    """Per stimulus, per (method, level), and what they suggest."""

    stimuli: pd.DataFrame
    """One row per stimulus: scene, method, level, each rater's mean rating, their mean and
    the mean differential score (NaN for hidden references and tests without one)."""
    levels: pd.DataFrame
    """One row per (method, level): ratings, mean rating, mean differential score."""
    raters: list[str]
    hints: list[str] = field(default_factory=list)
    """What to look at before inviting anyone; empty when nothing stands out."""


def _row_means(values: np.ndarray) -> np.ndarray:
    """Row means over the finite values (NaN for a row without any), without a warning."""
    finite = np.isfinite(values)
    counts = finite.sum(axis=1)
    sums = np.where(finite, values, 0.0).sum(axis=1)
    return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def stimulus_table(rs: RatingSet) -> pd.DataFrame:
    """Per stimulus: each rater's mean rating, their mean and the differential score."""
    means = rs.rater_means()
    table = rs.stimuli[["scene", "method", "level", "is_hidden_reference"]].copy()
    for k, rater in enumerate(rs.raters):
        table[rater] = means[:, k]
    ref = rs.reference_index()
    tests = (ref >= 0) & ~rs.hidden_reference_mask
    diffs = np.full(means.shape, np.nan)
    diffs[tests] = means[ref[tests]] - means[tests]
    table["mean"] = _row_means(means)
    table["differential"] = _row_means(diffs)
    return table


def level_table(stimuli: pd.DataFrame, rs: RatingSet) -> pd.DataFrame:
    """Per (method, level) of the test videos: the number of ratings, the mean rating and
    the mean differential score (over scenes and raters)."""
    tests = ~stimuli["is_hidden_reference"].to_numpy(dtype=bool)
    counts = np.isfinite(rs.scores).sum(axis=(1, 2))
    frame = stimuli.loc[tests, ["method", "level", "mean", "differential"]].assign(
        ratings=counts[tests])
    frame["level"] = frame["level"].astype(int)
    return (frame.groupby(["method", "level"], sort=True)
            .agg(ratings=("ratings", "sum"), mean=("mean", "mean"),
                 differential=("differential", "mean"))
            .reset_index())


def _num(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.0f}"


def reversed_levels(dmos: pd.DataFrame, span: float) -> list[str]:
    """The methods whose mean DMOS falls from the lowest level (meant to be the strongest) to their
    mildest level by more than :data:`FLAT_SHARE` of the scale, in words: the report's form of
    the pilot's first hint, for a study whose pilot was skipped or read as a report."""
    tests = dmos[~dmos["is_hidden_reference"].astype(bool)].dropna(subset=["level"])
    out = []
    for method, rows in tests.groupby("method", sort=True):
        means = rows.groupby(rows["level"].astype(int))["dmos"].mean().dropna()
        if len(means) < 2:
            continue
        lo, hi = int(means.index.min()), int(means.index.max())
        if means[hi] - means[lo] < -FLAT_SHARE * span:
            out.append(f"{method}: DMOS falls from {_num(means[lo])} at level {lo} (meant to "
                       f"be the strongest distortion) to {_num(means[hi])} at level {hi} (the "
                       "mildest): the levels look numbered the wrong way round, so every "
                       "level-wise result of this method reads backwards (renumber the files "
                       "or map them in a CSV before the next study)")
    return out


def level_hints(levels: pd.DataFrame, span: float) -> list[str]:
    """Per method with two levels or more: reversed or flat ratings; per method: a strongest
    level nobody saw, a mildest level far from the reference."""
    hints = []
    for method, rows in levels.groupby("method", sort=True):
        rows = rows.sort_values("level")
        strong, mild = rows.iloc[0], rows.iloc[-1]
        name = f"{method}: "
        if len(rows) >= 2 and math.isfinite(strong["mean"]) and math.isfinite(mild["mean"]):
            rise = float(mild["mean"] - strong["mean"])
            if rise < -FLAT_SHARE * span:
                hints.append(
                    f"{name}level {int(strong['level'])} (meant to be the strongest) was rated "
                    f"{_num(strong['mean'])} and level {int(mild['level'])} (the mildest) "
                    f"{_num(mild['mean'])}: the levels look numbered the wrong way round; "
                    "the lowest level must be the strongest distortion (renumber the files or map "
                    "them in a CSV, run init again, then pilot again: this pilot ran on the "
                    "old numbering)")
                continue
            if abs(rise) <= FLAT_SHARE * span:
                hints.append(f"{name}levels {int(strong['level'])} to {int(mild['level'])} "
                             f"were rated alike ({_num(strong['mean'])} and "
                             f"{_num(mild['mean'])}): the levels may be too close together")
        if math.isfinite(strong["differential"]) and strong["differential"] < UNSEEN_SHARE * span:
            below = (f"only {_num(strong['differential'])} below its reference"
                     if strong["differential"] >= 0.5 else "no lower than its reference")
            hints.append(f"{name}even the strongest level (L{int(strong['level'])}) was rated "
                         f"{below}: the distortion is hardly seen; consider a stronger level")
        elif len(rows) >= 2 and math.isfinite(mild["differential"]) and \
                mild["differential"] > NO_THRESHOLD_SHARE * span:
            hints.append(f"{name}even the mildest level (L{int(mild['level'])}) was rated "
                         f"{_num(mild['differential'])} below its reference: no level comes "
                         "near the threshold of visibility; consider a milder level")
    return hints


def rater_hints(stimuli: pd.DataFrame, rs: RatingSet) -> list[str]:
    """Raters who used a narrow part of the scale, or rated the hidden references low."""
    span = rs.scale_max - rs.scale_min
    hidden = stimuli["is_hidden_reference"].to_numpy(dtype=bool)
    hints = []
    for k, rater in enumerate(rs.raters):
        values = stimuli[rater].to_numpy(dtype=float)
        seen = rs.scores[:, k, :][np.isfinite(rs.scores[:, k, :])]  # every rating given
        if seen.size >= 3 and seen.max() - seen.min() < NARROW_SHARE * span:
            hints.append(f"{rater} used only {_num(seen.min())}-{_num(seen.max())} of the "
                         f"{_num(rs.scale_min)}-{_num(rs.scale_max)} scale: the briefing and "
                         "the practice should show the range of the distortions")
        refs = values[hidden & np.isfinite(values)]
        if refs.size and refs.mean() < rs.scale_min + 0.5 * span:
            hints.append(f"{rater} rated the hidden references {_num(refs.mean())} on "
                         "average, in the lower half of the scale: were they told that "
                         "some test videos are the reference itself?")
    return hints


def pilot_view(rs: RatingSet) -> PilotView:
    """The pilot's ratings by stimulus and by level, and what stands out."""
    stimuli = stimulus_table(rs)
    levels = level_table(stimuli, rs)
    span = rs.scale_max - rs.scale_min
    return PilotView(stimuli, levels, list(rs.raters),
                     level_hints(levels, span) + rater_hints(stimuli, rs))


def pilot_lines(view: PilotView, rs: RatingSet) -> list[str]:
    """The terminal's text: the raters, the level table, the hints."""
    info = rs.rater_info
    out = []
    for rater in view.raters:
        row = info.loc[rater] if info is not None and rater in info.index else None
        facts = [f"{int(np.isfinite(rs.scores[:, view.raters.index(rater)]).sum())} ratings"]
        if row is not None:
            if math.isfinite(float(row.get("minutes", math.nan))):
                facts.append(f"{float(row['minutes']):.1f} min in the study")
            if row.get("timing_mode") == "paced-pilot":
                facts.append("paced on the clock without vsync")
            drops = int(row.get("trials_with_drops", 0) or 0)
            shown = int(row.get("presentations", 0) or 0)
            requeued = int(row.get("requeued", 0) or 0)
            if drops:  # counted per presentation: a re-queued trial was shown twice
                facts.append(f"dropped frames in {drops} of {shown} presentations" + (
                    f" ({requeued} re-queued and shown again)" if requeued else ""))
        out.append(f"{rater}: " + ", ".join(facts))
    mirrored = (f" (ratings mirrored to higher-is-better: {_num(rs.scale_min)} + "
                f"{_num(rs.scale_max)} - rating)" if rs.scale_direction == "lower_is_better"
                else "")
    out.append("mean rating (and its reference's minus it) per method and level; the lowest "
               f"level is meant to be the strongest{mirrored}:")
    refs = view.stimuli.loc[view.stimuli["is_hidden_reference"].astype(bool), "mean"]
    for method, rows in view.levels.groupby("method", sort=True):
        cells = [f"L{int(r.level)} {_num(r.mean)} ({_num(r.differential)})"
                 for r in rows.itertuples()]
        out.append(f"  {method}: " + ", ".join(cells))
    if len(refs):
        out.append(f"  hidden references: {_num(float(refs.mean()))}")
    out += ([f"look at: {h}" for h in view.hints] if view.hints else
            ["nothing stands out in the levels or in the use of the scale"])
    return out
