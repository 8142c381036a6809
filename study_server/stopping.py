"""The stopping rule: when the study has enough ratings, and how many participants it still
needs.

The experimenter sets a target (``serve --target-mean-ci``, ``--target-max-ci``,
``--target-ratings``): DMOS 95 % CI widths (mean and widest over the conditions, on the
rating scale) or a ratings budget. After each refresh of the statistics the server records
the widths with the number of raters behind them (one point per number of raters, the latest
kept). How the widths shrink is fitted as ``width = c * raters ** -alpha`` by least squares
in log-log over the points with at least three raters (``alpha`` is about 1/2 once the
t quantile of small panels has settled); the participants still needed are where that curve
meets the target. "Target reached" when every target set is met.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

MIN_RATERS_FOR_FIT = 3
ALPHA_RANGE = (0.1, 2.0)


@dataclass(frozen=True)
class StoppingTarget:
    """What "enough" means for this study (all that are set must be met)."""

    mean_ci_width: float | None = None
    max_ci_width: float | None = None
    ratings: int | None = None
    close_at_target: bool = False

    @property
    def is_set(self) -> bool:
        return any(v is not None for v in (self.mean_ci_width, self.max_ci_width,
                                           self.ratings))

    def describe(self) -> str:
        parts = []
        if self.mean_ci_width is not None:
            parts.append(f"mean DMOS 95 % CI width <= {self.mean_ci_width:g}")
        if self.max_ci_width is not None:
            parts.append(f"widest DMOS 95 % CI <= {self.max_ci_width:g}")
        if self.ratings is not None:
            parts.append(f"{self.ratings} ratings")
        return " and ".join(parts) or "none"


@dataclass(frozen=True)
class WidthPoint:
    """The DMOS interval widths with ``raters`` raters (and ``ratings`` ratings) in."""

    raters: int
    ratings: int
    mean_width: float
    max_width: float


@dataclass(frozen=True)
class Decay:
    """``width = c * raters ** -alpha`` fitted on the recorded points."""

    c: float
    alpha: float

    def width(self, raters: float) -> float:
        return self.c * raters ** -self.alpha

    def raters_for(self, width: float) -> float:
        return (self.c / width) ** (1.0 / self.alpha)


@dataclass(frozen=True)
class StoppingStatus:
    target: StoppingTarget
    current: WidthPoint | None
    reached: bool
    met: dict[str, bool] = field(default_factory=dict)
    """Per target set: whether it is met now."""
    projected_raters: dict[str, float] = field(default_factory=dict)
    """Per width target: the raters the fitted decay needs to meet it."""
    more_raters: int | None = None
    """Participants still needed (the largest over the width targets and the ratings budget),
    when projectable."""
    decay: dict[str, Decay] = field(default_factory=dict)


def fit_decay(points: list[WidthPoint], which: str) -> Decay | None:
    """The decay of ``mean_width`` or ``max_width`` with raters (None: too few points)."""
    use = [p for p in points if p.raters >= MIN_RATERS_FOR_FIT
           and math.isfinite(getattr(p, which)) and getattr(p, which) > 0]
    if len({p.raters for p in use}) < 2:
        return None
    x = np.log([p.raters for p in use])
    y = np.log([getattr(p, which) for p in use])
    slope = np.polyfit(x, y, 1)[0]
    alpha = float(np.clip(-slope, *ALPHA_RANGE))
    # refit the level with the slope held in range, through the points' centre
    c = float(np.exp(np.mean(y + alpha * x)))
    return Decay(c, alpha)


def evaluate(target: StoppingTarget, points: list[WidthPoint], n_ratings: int,
             current: WidthPoint | None) -> StoppingStatus:
    """Where the study stands against ``target``: ``current`` holds the widths of the data as
    it is now (None when no DMOS could be computed), ``points`` the recorded history the
    decay is fitted on. ``current`` is given, not taken from the history, because a point
    recorded before a withdrawal describes ratings that are no longer there."""
    met: dict[str, bool] = {}
    projected: dict[str, float] = {}
    decays: dict[str, Decay] = {}
    for name, goal, which in (("mean CI width", target.mean_ci_width, "mean_width"),
                              ("widest CI", target.max_ci_width, "max_width")):
        if goal is None:
            continue
        met[name] = current is not None and getattr(current, which) <= goal
        decay = fit_decay(points, which)
        if decay is not None:
            decays[name] = decay
            projected[name] = decay.raters_for(goal)
    if target.ratings is not None:
        met["ratings"] = n_ratings >= target.ratings
    reached = target.is_set and bool(met) and all(met.values())
    more = None
    unmet = [raters for name, raters in projected.items() if not met[name]]
    if current is not None and unmet:
        # the fitted curve can pass below the current point: an unmet target needs one more
        more = max(1, math.ceil(max(unmet) - current.raters - 1e-9))
    elif current is not None and projected:
        more = 0
    if current is not None and met.get("ratings") is False and n_ratings > 0:
        # a ratings budget not met: the participants it takes at the ratings each gave so far
        per_rater = n_ratings / max(current.raters, 1)
        need = max(1, math.ceil((target.ratings - n_ratings) / per_rater - 1e-9))
        more = need if more is None else max(more, need)
    if reached:
        more = 0
    return StoppingStatus(target, current, reached, met, projected, more, decays)
