"""Coverage of the metric intervals by orientation: the bias-corrected percentile interval
the analysis uses against the basic (reversed) interval it used before, from the same
resamples of the same simulated studies (``bench_coverage.py``'s process), for PLCC and RMSE.

With few stimuli the resamples' PLCCs crowd towards 1 (a refitted logistic overfits
resamples that repeat stimuli); the basic interval mirrors that tail into low lower bounds.

    .venv/bin/python benchmarks/bench_interval_orientation.py --scenes 2 --conditions 8 \\
        --studies 400

Measured here (2 cores, 12 raters x 2 repetitions, 400 resamples, model mos): 16 conditions,
400 studies: PLCC coverage 0.975 / 0.950 (basic 0.993 / 0.965), RMSE 0.983 / 0.960 (basic
0.925 / 0.907); 32 conditions, 300 studies: PLCC 0.947 / 0.953 (basic 0.940 / 0.950); 72
conditions, 200 studies: PLCC 0.950 / 0.945 (basic 0.950 / 0.950).
"""

from __future__ import annotations

import argparse
import time
from types import SimpleNamespace

import bench_coverage as bc
import numpy as np

import analysis.metrics as am
from analysis.scores import dmos_table, fit_scores

_used = am._interval
_seen: list[tuple] = []


def _recording(point, ref, boot, kind, *, factor=1.0):
    """The analysis' interval, recorded beside the basic one from the same resamples."""
    lo, hi = _used(point, ref, boot, kind, factor=factor)
    b = boot[np.isfinite(boot)]
    if np.isfinite(lo):
        if kind == "corr":
            fwd, inv = (lambda x: np.arctanh(np.clip(x, -am.CORR_CLIP, am.CORR_CLIP))), np.tanh
        else:
            fwd, inv = (lambda x: np.log(np.maximum(x, 1e-12))), np.exp
        lo_q, mid, hi_q = np.percentile(fwd(b), [2.5, 50.0, 97.5])
        centre = fwd(np.array(point)) - (mid - fwd(np.array(ref)))
        basic = (float(inv(centre - factor * (hi_q - mid))),
                 float(inv(centre + factor * (mid - lo_q))))
        _seen.append((point, lo, hi, *basic))
    return lo, hi


def true_rmse(seed: int) -> dict[str, float]:
    """Each metric's RMSE against the true DMOS after its best mapping (as ``true_plcc``)."""
    rng = np.random.default_rng([seed, 99])
    d = bc.draw_dmos(rng, 400_000)
    ref = rng.uniform(75, 82, d.size)
    truth = bc.expected_rating(ref + d - 100) - bc.expected_rating(ref) + 100
    out = {}
    for name, sd in bc.METRIC_SD.items():
        m = d + rng.normal(0, sd, d.size)
        mapping = bc.fit_mapping(m[:40_000], truth[:40_000])
        out[name] = float(np.sqrt(np.mean((mapping(m) - truth) ** 2)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", type=int, default=400)
    parser.add_argument("--scenes", type=int, default=2)
    parser.add_argument("--conditions", type=int, default=8, help="per scene (8)")
    parser.add_argument("--raters", type=int, default=12)
    parser.add_argument("--reps", type=int, default=2)
    parser.add_argument("--boot", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    a = parser.parse_args()
    args = SimpleNamespace(**vars(a), model="mos")
    am._interval = _recording
    truths = {"plcc": bc.true_plcc(a.seed), "rmse": true_rmse(a.seed)}
    rows = {(stat, name): [] for stat in truths for name in bc.METRIC_SD}
    t0 = time.perf_counter()
    for k in range(a.studies):
        rs, _, metrics = bc.simulate(np.random.default_rng([a.seed, k]), args)
        res = fit_scores(rs, "mos", n_boot=a.boot, seed=k)
        _seen.clear()
        v = am.validate_metrics(dmos_table(rs, res), metrics, boot=res.bootstrap,
                                n_boot=a.boot, seed=k)
        t = v.table.set_index("metric")
        for (stat, name), out in rows.items():
            point, lo = t.loc[name, stat], t.loc[name, f"{stat}_ci95_low"]
            out += [rec for rec in _seen if rec[0] == point and rec[1] == lo][:1]
    print(f"{a.studies} studies of {a.scenes * a.conditions} conditions, {a.raters} raters x "
          f"{a.reps}, {a.boot} resamples, {time.perf_counter() - t0:.0f} s")
    for (stat, name), recs in rows.items():
        r = np.array(recs, dtype=float)
        truth = truths[stat][name]
        used = (r[:, 1] <= truth) & (truth <= r[:, 2])
        basic = (r[:, 3] <= truth) & (truth <= r[:, 4])
        se = np.sqrt(0.95 * 0.05 / len(r))
        print(f"{stat.upper()} {name} (true {truth:.3f}): coverage {used.mean():.3f}, width "
              f"{np.mean(r[:, 2] - r[:, 1]):.3f}; basic {basic.mean():.3f}, width "
              f"{np.mean(r[:, 4] - r[:, 3]):.3f} (s.e. at 0.95: {se:.3f}, n {len(r)})")


if __name__ == "__main__":
    main()
