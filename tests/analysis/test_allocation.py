"""Adaptive allocation's forecast and block plan, against hand computations and a brute-force
greedy written here; and the fit on simulated ratings whose noisiest scene is known."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from analysis.allocation import (
    AllocationFit,
    allocation_fit,
    forecast_halfwidth,
    plan_block,
)
from analysis.data import RatingSet
from analysis.errors import AnalysisError


def _fit(half=(0.0, 6.0, 3.0, 0.0, 4.0, 4.0), share=(1.0, 0.6, 0.7, 1.0, 0.5, 0.5),
         n=(10, 10, 10, 10, 10, 10)) -> AllocationFit:
    """Two scenes: hidden reference R1 (row 0) with conditions 1 and 2, R2 (row 3) with 4, 5."""
    return AllocationFit(["R1", "A1", "A2", "R2", "B1", "B2"], np.array(half, float),
                         np.array(share, float), np.array([0, 0, 0, 3, 3, 3]),
                         np.array([True, False, False, True, False, False]),
                         np.array(n, float))


def test_forecast_scales_each_part_with_its_own_count():
    fit = _fit()
    assert np.allclose(forecast_halfwidth(fit, fit.ratings), fit.halfwidth)
    assert np.allclose(forecast_halfwidth(fit, 2 * fit.ratings), fit.halfwidth / np.sqrt(2))
    counts = fit.ratings.copy()
    counts[0] = 40  # the first reference rated four times as often
    h = forecast_halfwidth(fit, counts)
    assert h[1] == pytest.approx(6.0 * np.sqrt(0.6 + 0.4 / 4))
    assert h[2] == pytest.approx(3.0 * np.sqrt(0.7 + 0.3 / 4))
    assert np.allclose(h[3:], fit.halfwidth[3:]) and h[0] == 0.0


def _brute_force(fit: AllocationFit, size: int, cap: int, power: float) -> np.ndarray:
    """The greedy plan, the slow way: try every stimulus, keep the lowest objective."""
    counts = fit.ratings.copy()
    block = np.zeros(len(counts), int)
    for _ in range(size):
        best, best_cost = None, np.inf
        for e in range(len(counts)):
            if block[e] >= cap:
                continue
            trial = counts.copy()
            trial[e] += 1
            cost = float(np.sum(forecast_halfwidth(fit, trial) ** power))
            if best is None or cost < best_cost - 1e-12 * best_cost:
                best, best_cost = e, cost
        block[best] += 1
        counts[best] += 1
    return block


@pytest.mark.parametrize("power", [1.0, 2.0, 16.0])
def test_the_plan_is_the_greedy_minimum_of_the_objective(power):
    fit = _fit()
    plan = plan_block(fit, 9, max_per_block=3, power=power)
    assert np.array_equal(plan, _brute_force(fit, 9, 3, power))
    assert plan.sum() == 9 and plan.max() <= 3


def test_the_widest_scene_gets_the_ratings_and_its_reference_too():
    plan = plan_block(_fit(), 6, max_per_block=3)
    # A1 (6.0) is widest; its reference R1 narrows A1 and A2 together
    assert plan[1] >= 2 and plan[0] >= 1
    assert plan[[4, 5]].sum() <= plan[[0, 1, 2]].sum()


def test_pending_ratings_count_as_given():
    fit = _fit()
    without = plan_block(fit, 4, max_per_block=3)
    pending = np.zeros(6)
    pending[[0, 1, 2]] = 40  # scene 1 is already being rated by others
    with_pending = plan_block(fit, 4, pending=pending, max_per_block=3)
    assert without[[0, 1, 2]].sum() > with_pending[[0, 1, 2]].sum()


def test_impossible_blocks_are_refused():
    with pytest.raises(AnalysisError, match="at least one trial"):
        plan_block(_fit(), 0)
    with pytest.raises(AnalysisError, match="at most 2 times"):
        plan_block(_fit(), 13, max_per_block=2)


def _simulated(noisy_scene_sd: float, seed: int = 0) -> RatingSet:
    """4 scenes x (hidden reference + 3 conditions), 12 raters x 2 repetitions; scene S3's
    ratings are ``noisy_scene_sd`` noisier than the others' (content ambiguity)."""
    rng = np.random.default_rng(seed)
    rows, q, amb = [], [], []
    for s in range(4):
        for k in range(4):
            rows.append({"stimulus": f"S{s}" if k == 0 else f"S{s}_c{k}",
                         "reference": f"S{s}", "scene": f"S{s}",
                         "method": "reference" if k == 0 else "blur",
                         "level": None if k == 0 else k, "is_hidden_reference": k == 0})
            q.append(85.0 if k == 0 else 85.0 - 15 * k)
            amb.append(noisy_scene_sd if s == 3 else 3.0)
    stimuli = pd.DataFrame(rows).set_index("stimulus")
    stimuli["level"] = stimuli["level"].astype("Int64")
    bias = rng.normal(0, 4, 12)
    noise = rng.normal(0, 1, (16, 12, 2)) * np.hypot(5.0, np.array(amb))[:, None, None]
    scores = np.clip(np.array(q)[:, None, None] + bias[None, :, None] + noise, 0, 100)
    return RatingSet(stimuli, [f"R{k}" for k in range(12)], scores, 0.0, 100.0, 100.0)


def test_a_fit_on_ratings_puts_the_next_block_on_the_noisiest_scene():
    rs = _simulated(25.0)
    fit = allocation_fit(rs, n_boot=200, seed=1)
    assert fit.stimulus_ids == rs.stimulus_ids
    assert np.array_equal(fit.ratings, np.isfinite(rs.scores).sum(axis=(1, 2)))
    assert np.all(fit.halfwidth[rs.hidden_reference_mask] == 0)
    assert np.all((fit.own_share >= 0) & (fit.own_share <= 1))
    noisy = np.array([s.startswith("S3") for s in rs.stimulus_ids])
    cond = ~rs.hidden_reference_mask
    assert fit.halfwidth[noisy & cond].min() > fit.halfwidth[~noisy & cond].max()
    plan = plan_block(fit, 16, max_per_block=3)
    assert plan[noisy].sum() >= 10  # most of the block goes to the noisy scene


@pytest.mark.parametrize("last", [None, 1])
def test_no_stimulus_gets_so_many_trials_that_the_block_must_repeat_it(last):
    """One much wider condition took 3 of a 4-trial block (the default cap), and no order of
    such a block avoids showing it twice in a row."""
    from session_store.schedule import ScheduleItem, order_trials

    fit = _fit(half=(0.0, 30.0, 1.0, 0.0, 1.0, 1.0))
    plan = plan_block(fit, 4, max_per_block=3, last=last)
    assert plan.sum() == 4 and plan.max() <= 2
    if last is not None:
        assert plan[last] <= 4 // 2  # after it: at most half the block, rounded down
    items = [ScheduleItem(s, "R", False) for s in fit.stimulus_ids]
    for seed in range(30):
        prev = None if last is None else fit.stimulus_ids[last]
        order = order_trials(items, dict(zip(fit.stimulus_ids, plan.tolist(), strict=True)),
                             seed, last=prev)
        shown = [prev, *[t.stimulus for t in order]]
        assert all(a != b for a, b in itertools.pairwise(shown)), shown
