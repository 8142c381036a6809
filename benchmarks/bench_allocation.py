"""Does adaptive allocation buy the same DMOS precision with fewer ratings?

Simulated studies at the paper's scale, analysed exactly as ``cgvq-analyze`` does (SUREAL's
MLE and the rater-bootstrap DMOS intervals), under two designs:

- ``full``: every participant rates every stimulus three times (the paper's design);
- ``adaptive``: every participant rates every stimulus once (block 1, which keeps rater bias,
  inconsistency, screening and ICC estimable on a complete matrix), then two blocks of as many
  trials chosen by :mod:`analysis.allocation` from the ratings in so far (the first
  ``--warmup`` participants get uniform blocks instead); the same session length.

**Ground truth from a real dataset.** SUREAL's MLE is fitted to the Netflix public dataset
(``../shared/data/sureal``: 79 stimuli with 9 hidden references, 26 raters, ACR 1-5) and its
estimates, mapped linearly to 0..100, become the generative model: quality of each stimulus
(plus N(0, 2^2) jitter per study), content ambiguity resampled per content from the fitted
ones, rater bias ~ N(0, sd of the fitted biases), rater inconsistency resampled from the
fitted ones (floored at 1). A rating is ``clip(q + b + sqrt(v^2 + a^2) e, 0, 100)``. The true
DMOS of a condition is ``E[rating(v)] - E[rating(ref)] + 100`` over the rater population and
the noise, clipping included (exact for the normal model, averaged over the inconsistencies).

Printed: ratings ``adaptive`` needs to reach the mean DMOS CI width ``full`` reaches with 20
participants; at equal budget the mean and maximum CI widths, RMSE and SRCC of DMOS against
the truth, and 95 % CI coverage with its Monte Carlo standard error (studies as the
independent units); ratings per stimulus; the time of one allocation step (the refit and the
block plan, as the server runs it between participants).

    .venv/bin/python benchmarks/bench_allocation.py [--studies 20] [--jobs 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from multiprocessing import Pool
from pathlib import Path

import numpy as np
from scipy import stats

from analysis.allocation import POWER, allocation_fit, plan_block
from analysis.data import RatingSet
from analysis.scores import dmos_table, fit_scores
from analysis.sureal_io import load_sureal

DATASET = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "sureal" / \
    "NFLX_dataset_public_raw.py"
SCALE = 25.0  # ACR 1..5 to 0..100
REPS = 3
CHECKPOINTS = (3, 5, 8, 10, 12, 14, 16, 17, 18, 19, 20)


@dataclass(frozen=True)
class World:
    """The generative model fitted on the real dataset."""

    template: RatingSet
    quality: np.ndarray
    content: np.ndarray  # content index of every stimulus
    ambiguity: np.ndarray  # fitted, per content (0..100 scale)
    bias_sd: float
    inconsistency: np.ndarray  # fitted, per rater (0..100 scale)


def fitted_world(path: Path) -> World:
    rs = load_sureal(path)
    res = fit_scores(rs, "mle", n_boot=50)
    contents = list(dict.fromkeys(rs.stimuli["reference"]))
    content = np.array([contents.index(c) for c in rs.stimuli["reference"]])
    amb = dict(zip(res.content, res.content_ambiguity, strict=True))
    return World(rs, (res.quality - rs.scale_min) * SCALE, content,
                 np.array([amb[c] for c in contents]) * SCALE,
                 float(np.std(res.rater_bias)) * SCALE,
                 np.maximum(res.rater_inconsistency * SCALE, 1.0))


def expected_rating(q: np.ndarray, amb: np.ndarray, world: World) -> np.ndarray:
    """E[clip(q + b + sqrt(v^2 + a^2) e, 0, 100)] over b, e and the fitted v's."""
    sd = np.sqrt(world.bias_sd ** 2 + world.inconsistency[None, :] ** 2 + amb[:, None] ** 2)
    q = q[:, None]
    lo, hi = -q / sd, (100.0 - q) / sd
    inside = q * (stats.norm.cdf(hi) - stats.norm.cdf(lo)) + \
        sd * (stats.norm.pdf(lo) - stats.norm.pdf(hi))
    return (inside + 100.0 * stats.norm.sf(hi)).mean(axis=1)


def rating_variance(q: np.ndarray, amb: np.ndarray, world: World) -> np.ndarray:
    """Var[clip(q + sqrt(v^2 + a^2) e, 0, 100)] per stimulus, averaged over the fitted v's
    (the variance one bias-corrected rating carries), by Gauss-Hermite quadrature."""
    z, w = np.polynomial.hermite_e.hermegauss(80)
    w = w / w.sum()
    sd = np.sqrt(world.inconsistency[None, :, None] ** 2 + amb[:, None, None] ** 2)
    y = np.clip(q[:, None, None] + sd * z[None, None, :], 0, 100)
    m1, m2 = (y * w).sum(axis=2), (y * y * w).sum(axis=2)
    return (m2 - m1 * m1).mean(axis=1)


def oracle_ratios(world: World, n_raters: int) -> tuple[float, float]:
    """The best any allocation could do with the per-stimulus variances known (DMOS variance
    s_v^2 / n_v + s_ref^2 / n_ref, every stimulus at least once per participant, the same
    budget): (mean width, max width) relative to the full design."""
    from scipy.optimize import minimize

    s2 = rating_variance(world.quality, world.ambiguity[world.content], world)
    ref = world.template.reference_index()
    cond = ~world.template.hidden_reference_mask
    e = s2.size
    budget, floor = REPS * n_raters * e, float(n_raters)

    def widths(n: np.ndarray) -> np.ndarray:
        return np.sqrt(s2 / n + s2[ref] / n[ref])[cond]

    full = widths(np.full(e, budget / e))
    out = []
    for power in (1.0, 16.0):
        def cost(x: np.ndarray, p: float = power) -> float:
            return float(np.sum((widths(np.exp(x)) / full.max()) ** p))

        x0 = np.full(e, np.log(budget / e))
        res = minimize(cost, x0, method="SLSQP", bounds=[(np.log(floor), None)] * e,
                       constraints=[{"type": "eq", "fun": lambda x: np.exp(x).sum() - budget}],
                       options={"maxiter": 500, "ftol": 1e-12})
        w = widths(np.exp(res.x))
        out.append(float(w.mean() / full.mean()) if power == 1.0 else
                   float(w.max() / full.max()))
    return out[0], out[1]


class Study:
    """One simulated study: its truth, its raters and the ratings given so far."""

    def __init__(self, world: World, seed: int, n_raters: int) -> None:
        self.world = world
        self.rng = np.random.default_rng([seed, 7])
        e = len(world.quality)
        self.q = world.quality + self.rng.normal(0, 2.0, e)
        amb = self.rng.choice(world.ambiguity, world.ambiguity.size)
        self.amb = amb[world.content]
        self.bias = self.rng.normal(0, world.bias_sd, n_raters)
        self.incons = self.rng.choice(world.inconsistency, n_raters)
        ref = world.template.reference_index()
        exp = expected_rating(self.q, self.amb, world)
        self.truth = exp - exp[ref] + 100.0
        self.cond = ~world.template.hidden_reference_mask
        self.ratings: list[list[list[float]]] = [[[] for _ in range(n_raters)]
                                                 for _ in range(e)]
        self.n_given = 0

    def rate(self, rater: int, block: np.ndarray) -> None:
        order = np.repeat(np.arange(block.size), block)
        self.rng.shuffle(order)
        sd = np.sqrt(self.incons[rater] ** 2 + self.amb[order] ** 2)
        x = np.clip(self.q[order] + self.bias[rater] + sd * self.rng.normal(size=order.size),
                    0, 100)
        for e, v in zip(order, x, strict=True):
            self.ratings[e][rater].append(float(v))
        self.n_given += order.size

    def rating_set(self, n_raters: int) -> RatingSet:
        reps = max(len(r) for row in self.ratings for r in row[:n_raters])
        arr = np.full((len(self.ratings), n_raters, reps), np.nan)
        for e, row in enumerate(self.ratings):
            for s in range(n_raters):
                arr[e, s, :len(row[s])] = row[s]
        t = self.world.template
        return RatingSet(t.stimuli, [f"R{s:02d}" for s in range(n_raters)], arr, 0.0, 100.0,
                         100.0, study="allocation")

    def evaluate(self, n_raters: int, seed: int) -> dict[str, float]:
        rs = self.rating_set(n_raters)
        res = fit_scores(rs, "mle", n_boot=500, seed=seed)
        table = dmos_table(rs, res)
        lo = table["ci95_low"].to_numpy()[self.cond]
        hi = table["ci95_high"].to_numpy()[self.cond]
        dm = table["dmos"].to_numpy()[self.cond]
        truth = self.truth[self.cond]
        width = hi - lo
        return {"ratings": self.n_given, "mean_w": float(np.nanmean(width)),
                "max_w": float(np.nanmax(width)),
                "rmse": float(np.sqrt(np.mean((dm - truth) ** 2))),
                "srcc": float(stats.spearmanr(dm, truth).statistic),
                "cover": float(np.mean((lo <= truth) & (truth <= hi))),
                "n_cond": int(truth.size)}


def run_study(args: tuple[int, str, argparse.Namespace, World]) -> dict:
    seed, design, opts, world = args
    study = Study(world, seed, opts.raters)
    e = len(world.quality)
    curve, steps = [], []
    for s in range(opts.raters):
        if design == "full" or s < opts.warmup:
            study.rate(s, np.full(e, REPS))
        else:
            study.rate(s, np.ones(e, dtype=int))  # block 1: every stimulus once
            for _ in range(REPS - 1):
                t0 = time.perf_counter()
                fit = allocation_fit(study.rating_set(s + 1), n_boot=opts.boot, seed=s)
                t1 = time.perf_counter()
                block = plan_block(fit, e, power=opts.power)
                steps.append((t1 - t0, time.perf_counter() - t1))
                study.rate(s, block)
        if s + 1 in CHECKPOINTS and s + 1 <= opts.raters:
            curve.append({"raters": s + 1, **study.evaluate(s + 1, seed)})
    per_stim = np.array([sum(len(r) for r in row) for row in study.ratings])
    return {"seed": seed, "design": design, "curve": curve, "steps": steps,
            "per_stimulus": per_stim.tolist(), "hidden": world.template.hidden_reference_mask}


def ratings_to_reach(curve: list[dict], width: float) -> tuple[float, bool]:
    """Ratings at which the mean width falls to ``width`` (log-log interpolation between
    checkpoints; extrapolated from the last three when it never does: flagged)."""
    r = np.array([c["ratings"] for c in curve], dtype=float)
    w = np.array([c["mean_w"] for c in curve])
    below = np.flatnonzero(w <= width)
    if below.size and below[0] > 0:
        k = below[0]
        x0, x1, y0, y1 = np.log(r[k - 1]), np.log(r[k]), np.log(w[k - 1]), np.log(w[k])
        return float(np.exp(x0 + (np.log(width) - y0) * (x1 - x0) / (y1 - y0))), False
    slope, icept = np.polyfit(np.log(r[-3:]), np.log(w[-3:]), 1)
    return float(np.exp((np.log(width) - icept) / slope)), True


def _mean_se(values: list[float]) -> tuple[float, float]:
    a = np.asarray(values, dtype=float)
    return float(a.mean()), float(a.std(ddof=1) / np.sqrt(a.size)) if a.size > 1 else 0.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", type=int, default=20, help="seeds per design (20)")
    parser.add_argument("--raters", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=2,
                        help="participants with uniform blocks before adapting (2)")
    parser.add_argument("--boot", type=int, default=200,
                        help="bootstrap resamples in an allocation fit (200)")
    parser.add_argument("--power", type=float, default=POWER,
                        help=f"the plan's objective: sum of half-widths ** power ({POWER:g})")
    parser.add_argument("--jobs", type=int, default=2)
    opts = parser.parse_args()
    if not DATASET.is_file():
        print(f"error: {DATASET} is missing (the shared data folder beside the repository)",
              file=sys.stderr)
        return 2
    world = fitted_world(DATASET)
    t0 = time.perf_counter()
    tasks = [(seed, d, opts, world) for seed in range(opts.studies)
             for d in ("full", "adaptive")]
    with Pool(opts.jobs) as pool:
        results = pool.map(run_study, tasks, chunksize=1)
    elapsed = time.perf_counter() - t0
    full = {r["seed"]: r for r in results if r["design"] == "full"}
    adap = {r["seed"]: r for r in results if r["design"] == "adaptive"}
    e = len(world.quality)
    n_ref = int(world.template.hidden_reference_mask.sum())
    print(f"{opts.studies} simulated studies per design; {e} stimuli ({n_ref} "
          f"hidden references), {opts.raters} participants x {REPS * e} trials "
          f"= {opts.raters * REPS * e} ratings; world fitted on {DATASET.name}; "
          f"{elapsed:.0f} s on {opts.jobs} processes")
    print(f"fitted: rater bias s.d. {world.bias_sd:.1f}, inconsistency "
          f"{np.median(world.inconsistency):.1f} median ({world.inconsistency.min():.1f}-"
          f"{world.inconsistency.max():.1f}), content ambiguity {world.ambiguity.min():.1f}-"
          f"{world.ambiguity.max():.1f} (0..100 scale)")
    need, extrap = [], 0
    for seed, f in full.items():
        target = f["curve"][-1]["mean_w"]
        n, x = ratings_to_reach(adap[seed]["curve"], target)
        need.append(n / f["curve"][-1]["ratings"])
        extrap += x
    m, se = _mean_se(need)
    print(f"\nratings adaptive needs for full's mean DMOS CI width at {opts.raters} participants: "
          f"{100 * m:.1f} % of full's (s.e. {100 * se:.1f}; target <= 70 %)"
          + (f"; {extrap} of {len(need)} extrapolated" if extrap else ""))
    print(f"\nat equal budget ({opts.raters} participants):")
    print(f"{'':10s} {'mean CI':>8s} {'max CI':>8s} {'RMSE':>7s} {'SRCC':>7s} {'coverage':>9s} "
          f"{'MC s.e.':>8s}")
    last = {}
    for name, runs in (("full", full), ("adaptive", adap)):
        ends = [r["curve"][-1] for r in runs.values()]
        last[name] = ends
        cov, cov_se = _mean_se([c["cover"] for c in ends])
        print(f"{name:10s} {np.mean([c['mean_w'] for c in ends]):8.2f} "
              f"{np.mean([c['max_w'] for c in ends]):8.2f} "
              f"{np.mean([c['rmse'] for c in ends]):7.2f} "
              f"{np.mean([c['srcc'] for c in ends]):7.4f} {cov:9.4f} {cov_se:8.4f}"
              f"  {'within' if abs(cov - 0.95) <= 2 * cov_se else 'OUTSIDE'} 2 s.e. of 0.95")
    ratio_max = np.array([a["max_w"] / f["max_w"] for a, f in
                          zip(last["adaptive"], last["full"], strict=True)])
    ratio_mean = np.array([a["mean_w"] / f["mean_w"] for a, f in
                           zip(last["adaptive"], last["full"], strict=True)])
    ratio_rmse = np.array([a["rmse"] / f["rmse"] for a, f in
                           zip(last["adaptive"], last["full"], strict=True)])
    for label, ratio, goal in (("max CI width", ratio_max, "target: >= 25 % narrower"),
                               ("mean CI width", ratio_mean, ""),
                               ("RMSE", ratio_rmse, "target: no worse")):
        m, se = _mean_se(list(ratio))
        print(f"adaptive / full, {label}: {m:.3f} (s.e. {se:.3f}) {goal}")
    mean_bound, max_bound = oracle_ratios(world, opts.raters)
    print(f"\nbound under this model (variances known, widths ~ 1/sqrt(n), the same floor): "
          f"mean width x{mean_bound:.3f} (so at best {100 * mean_bound ** 2:.0f} % of the "
          f"ratings for full's mean width), max width x{max_bound:.3f}")
    print("\nmean CI width by participants (mean over studies):")
    print("participants " + " ".join(f"{c['raters']:6d}" for c in full[0]["curve"]))
    for name, runs in (("full", full), ("adaptive", adap)):
        widths = np.mean([[c["mean_w"] for c in r["curve"]] for r in runs.values()], axis=0)
        print(f"{name:12s} " + " ".join(f"{w:6.2f}" for w in widths))
    per = np.array([r["per_stimulus"] for r in adap.values()])
    hidden = adap[0]["hidden"]
    print(f"\nadaptive ratings per stimulus at {opts.raters} participants: conditions "
          f"{np.percentile(per[:, ~hidden], [0, 50, 100]).round().astype(int).tolist()} "
          f"(min/median/max), hidden references "
          f"{np.percentile(per[:, hidden], [0, 50, 100]).round().astype(int).tolist()}; "
          f"full: {opts.raters * REPS} each")
    steps = np.concatenate([r["steps"] for r in adap.values()])
    total = steps.sum(axis=1)
    print(f"allocation step ({e} stimuli, up to {opts.raters} participants, this machine, one "
          f"process each): refit (SUREAL MLE + {opts.boot} bootstrap resamples, in the "
          f"server's background) median {np.median(steps[:, 0]):.2f} s, 95th percentile "
          f"{np.percentile(steps[:, 0], 95):.2f} s, max {steps[:, 0].max():.2f} s; block plan "
          f"(the request) median {1000 * np.median(steps[:, 1]):.0f} ms, max "
          f"{1000 * steps[:, 1].max():.0f} ms; both: {np.mean(total < 1.0):.1%} of "
          f"{total.size} steps under 1 s (target < 1 s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
