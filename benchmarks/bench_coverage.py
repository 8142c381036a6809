"""Do the nominal 95% intervals of DMOS and of PLCC cover the truth 95% of the time?

Simulated studies with known truth, analysed exactly as ``cgvq-analyze`` does (score model,
DMOS CIs from the rater bootstrap, metric intervals from the two-way bootstrap with the mapping
refitted in every resample). Prints the coverage of each kind of interval with its Monte Carlo
standard error, and whether it lies within two standard errors of 0.95.

Each study: ``--scenes`` contents x ``--conditions`` distorted versions (spread over three
distortion methods) + the hidden references, ``--raters`` raters x ``--reps`` repetitions.
Rater s rates stimulus v as ``clip(Q(v) + b_s + v_s e, 0, 100)`` with b_s ~ N(0, 4^2),
v_s ~ U(4, 10), e ~ N(0, 1); references have Q ~ U(75, 82); a condition's true DMOS d is drawn
from N(72, 10^2) truncated to [45, 99] and Q(v) = Q(ref) + d - 100.

Truth: the true DMOS of a condition is E[rating(v)] - E[rating(ref)] + 100 over the rater
population and the rating noise, clipping included (computed exactly; without clipping it is
d). Two metrics score each condition as ``d + N(0, s^2)`` (s = 5 and 12); a metric's true
PLCC is its correlation with the true DMOS in the population of conditions, after the best
monotone mapping: computed once from 400,000 draws of the same process.

Coverage is pooled over stimuli and studies; its standard error treats the studies as the
independent units (stimuli of one study share raters, so they are not independent).

    .venv/bin/python benchmarks/bench_coverage.py [--studies 200] [--model mle] [--boot 500]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd
from scipy import stats
from tqdm import tqdm

from analysis.data import RatingSet
from analysis.mapping import fit_mapping
from analysis.metrics import MetricScores, validate_metrics
from analysis.scores import dmos_table, fit_scores

METRIC_SD = {"metric-good": 5.0, "metric-weak": 12.0}
BIAS_SD = 4.0
INCONSISTENCY = (4.0, 10.0)
D_MEAN, D_SD, D_LO, D_HI = 72.0, 10.0, 45.0, 99.0


def draw_dmos(rng: np.random.Generator, n: int) -> np.ndarray:
    a, b = (D_LO - D_MEAN) / D_SD, (D_HI - D_MEAN) / D_SD
    return stats.truncnorm.rvs(a, b, loc=D_MEAN, scale=D_SD, size=n, random_state=rng)


def expected_rating(q: np.ndarray) -> np.ndarray:
    """E[clip(q + b + v e, 0, 100)] over b ~ N(0, BIAS_SD^2), v ~ U(INCONSISTENCY), e ~ N(0,1)."""
    v = np.linspace(*INCONSISTENCY, 61)
    sd = np.sqrt(BIAS_SD ** 2 + v ** 2)[None, :]
    q = np.asarray(q, dtype=float)[:, None]
    lo, hi = (0.0 - q) / sd, (100.0 - q) / sd
    # E[clip(X)] for X ~ N(q, sd^2): q + sd (pdf(lo) - pdf(hi)) - (q - 0) P(X<0)
    # + (100 - q) P(X>100), written out.
    mean_inside = q * (stats.norm.cdf(hi) - stats.norm.cdf(lo)) + sd * (stats.norm.pdf(lo)
                                                                        - stats.norm.pdf(hi))
    e = mean_inside + 100.0 * stats.norm.sf(hi)
    return np.trapezoid(e, v, axis=1) / (v[-1] - v[0])


def true_plcc(seed: int) -> dict[str, float]:
    rng = np.random.default_rng([seed, 99])
    d = draw_dmos(rng, 400_000)
    ref = rng.uniform(75, 82, d.size)
    truth = expected_rating(ref + d - 100) - expected_rating(ref) + 100
    out = {}
    for name, sd in METRIC_SD.items():
        m = d + rng.normal(0, sd, d.size)
        sub = slice(0, 40_000)  # the mapping from a large subsample, PLCC on all draws
        mapping = fit_mapping(m[sub], truth[sub])
        out[name] = float(np.corrcoef(mapping(m), truth)[0, 1])
    return out


def simulate(rng: np.random.Generator, args) -> tuple[RatingSet, np.ndarray, MetricScores]:
    n_cond = args.scenes * args.conditions
    ref_q = rng.uniform(75, 82, args.scenes)
    d = draw_dmos(rng, n_cond)
    scene = np.repeat(np.arange(args.scenes), args.conditions)
    q_cond = ref_q[scene] + d - 100
    methods = np.array(["m1", "m2", "m3"])[np.arange(n_cond) % 3]
    ids = [f"S{s:02d}_C{k:03d}" for k, s in enumerate(scene)]
    refs = [f"S{s:02d}" for s in range(args.scenes)]
    q = np.concatenate([q_cond, ref_q])
    bias = rng.normal(0, BIAS_SD, args.raters)
    incons = rng.uniform(*INCONSISTENCY, args.raters)
    noise = rng.normal(0, 1, (q.size, args.raters, args.reps))
    scores = np.clip(q[:, None, None] + bias[None, :, None] + incons[None, :, None] * noise,
                     0, 100)
    stimuli = pd.DataFrame({
        "reference": [refs[s] for s in scene] + refs,
        "scene": [refs[s] for s in scene] + refs,
        "method": list(methods) + ["reference"] * args.scenes,
        "level": pd.array([1] * n_cond + [None] * args.scenes, dtype="Int64"),
        "is_hidden_reference": [False] * n_cond + [True] * args.scenes},
        index=pd.Index(ids + refs, name="stimulus"))
    rs = RatingSet(stimuli, [f"R{k:02d}" for k in range(args.raters)], scores, 0.0, 100.0,
                   100.0, study="coverage")
    truth = expected_rating(q_cond) - expected_rating(ref_q[scene]) + 100
    rows = [pd.DataFrame({"stimulus": ids, "reference": [refs[s] for s in scene],
                          "metric": name, "score": d + rng.normal(0, sd, n_cond),
                          "direction": "higher-better"})
            for name, sd in METRIC_SD.items()]
    return rs, truth, MetricScores(pd.concat(rows, ignore_index=True))


def _line(name: str, hits: np.ndarray, per_study: np.ndarray | None = None) -> str:
    p = float(hits.mean())
    if per_study is None:
        se = float(np.sqrt(p * (1 - p) / hits.size))
    else:
        se = float(per_study.std(ddof=1) / np.sqrt(per_study.size))
    ok = abs(p - 0.95) <= 2 * se
    return (f"{name:30s} coverage {p:.4f}  MC s.e. {se:.4f}  n = {hits.size:6d}  "
            f"{'within' if ok else 'OUTSIDE'} 2 s.e. of 0.95")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", type=int, default=200)
    parser.add_argument("--model", default="mle", choices=("mle", "p910", "mos"))
    parser.add_argument("--boot", type=int, default=500, help="bootstrap resamples (500)")
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--conditions", type=int, default=9, help="per scene (9)")
    parser.add_argument("--raters", type=int, default=20)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    t0 = time.perf_counter()
    truth_r = true_plcc(args.seed)
    dmos_hits, dmos_study, quad_hits = [], [], []
    plcc_hits = {name: [] for name in METRIC_SD}
    widths = []
    for k in tqdm(range(args.studies), desc="studies", unit="study", mininterval=10):
        rng = np.random.default_rng([args.seed, k])
        rs, truth, metrics = simulate(rng, args)
        res = fit_scores(rs, args.model, n_boot=args.boot, seed=k)
        table = dmos_table(rs, res)
        cond = ~table["is_hidden_reference"].to_numpy()
        lo, hi = table["ci95_low"].to_numpy()[cond], table["ci95_high"].to_numpy()[cond]
        hit = (lo <= truth) & (truth <= hi)
        dmos_hits.append(hit)
        dmos_study.append(hit.mean())
        widths.append(np.mean(hi - lo))
        # the quadrature interval the analysis used before, for comparison
        ref = rs.reference_index()[cond]
        half_q = np.sqrt(res.quality_halfwidth[cond] ** 2 + res.quality_halfwidth[ref] ** 2)
        dm = table["dmos"].to_numpy()[cond]
        quad_hits.append(np.abs(dm - truth) <= half_q)
        v = validate_metrics(table, metrics, boot=res.bootstrap, n_boot=args.boot, seed=k)
        t = v.table.set_index("metric")
        for name in METRIC_SD:
            plcc_hits[name].append(t.loc[name, "plcc_ci95_low"] <= truth_r[name]
                                   <= t.loc[name, "plcc_ci95_high"])
    elapsed = time.perf_counter() - t0
    print(f"{args.studies} simulated studies, model {args.model}, {args.boot} bootstrap "
          f"resamples; {args.scenes * args.conditions} conditions + {args.scenes} references, "
          f"{args.raters} raters x {args.reps} repetitions; {elapsed:.0f} s "
          f"({elapsed / args.studies:.2f} s per study)")
    print("true PLCC: " + ", ".join(f"{k} {v:.4f}" for k, v in truth_r.items()))
    print(f"mean DMOS 95% CI width {np.mean(widths):.2f} (0..100 scale)")
    print(_line("DMOS (rater bootstrap)", np.concatenate(dmos_hits), np.array(dmos_study)))
    quad = np.concatenate(quad_hits)
    print(_line("DMOS (old: quadrature)", quad,
                np.array([h.mean() for h in quad_hits])))
    pooled = np.concatenate([np.array(h, dtype=float) for h in plcc_hits.values()])
    for name, hits in plcc_hits.items():
        print(_line(f"PLCC {name}", np.array(hits, dtype=float)))
    print(_line("PLCC pooled", pooled))


if __name__ == "__main__":
    main()
