"""Time the full analysis report of a CG-VQD-sized study.

20 raters x 240 ratings each (80 stimuli incl. 8 hidden references, 3 repetitions), one
random rater, ``--metrics`` metrics (default 2; the peer-metric set is about 12), 1000
bootstrap resamples and 1000 split-halves: reading, every analysis step (completeness rule,
screening, REML/pingouin ICC, SUREAL model, rater bootstrap, ceiling, CI curve, data
quality, two-way bootstrap with refitted mappings and all pairwise comparisons), the figures
and the report folder. Target: under 30 s on 2 cores. Prints the figures.

    .venv/bin/python benchmarks/bench_analysis.py [--boot 1000] [--splits 1000] [--model mle]
                                                  [--metrics 2]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.inputs import ratings_from_frame
from analysis.metrics import load_metric_scores
from analysis.pipeline import AnalysisConfig, run_analysis
from analysis.report import write_report
from analysis.synthetic import synthetic_study


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--boot", type=int, default=1000)
    parser.add_argument("--splits", type=int, default=1000)
    parser.add_argument("--model", default="mle")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs (median reported)")
    parser.add_argument("--metrics", type=int, default=2, help="metrics in the scores file")
    args = parser.parse_args()

    study = synthetic_study(n_scenes=8, methods=("denoise", "upscale", "interp"), levels=3,
                            n_raters=20, repetitions=3, n_outliers=1, noise_sd=8, bias_sd=5,
                            seed=0)
    per_rater = study.ratings.groupby("participant").size()
    assert (per_rater == 240).all(), per_rater
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rng = np.random.default_rng(0)
        cond = [s for s in study.quality.index if "_" in s]
        q = study.quality[cond].to_numpy()
        kinds = [(lambda x: x, 3.0, "higher-better"), (lambda x: -np.log(x), 0.2, "lower-better")]
        frames = [pd.DataFrame({"stimulus": cond, "reference": [c.split("_")[0] for c in cond],
                                "metric": f"metric-{k}",
                                "score": f(q) + rng.normal(0, sd * (1 + k // 2), len(q)),
                                "direction": direction})
                  for k in range(args.metrics) for f, sd, direction in [kinds[k % 2]]]
        pd.concat(frames).to_csv(tmp / "scores.csv", index=False)
        walls, cpus, steps = [], [], []
        for k in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            rs = ratings_from_frame(study.ratings, study.manifest)
            metrics = load_metric_scores([tmp / "scores.csv"])
            config = AnalysisConfig(model=args.model, n_boot=args.boot, n_splits=args.splits)
            analysis = run_analysis(rs, config, metrics, progress=False)
            t_report = time.perf_counter()
            write_report(analysis, tmp / f"report{k}")
            analysis.timings["report (figures, html, csv)"] = time.perf_counter() - t_report
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            steps.append(analysis.timings)
    best = int(np.argsort(walls)[len(walls) // 2])
    print(f"study: {rs.n_raters} raters x {rs.n_stimuli} stimuli x {rs.n_repetitions} "
          f"repetitions = {rs.n_ratings} ratings; model {args.model}; {args.boot} bootstrap "
          f"resamples; {args.splits} split-halves; {args.metrics} metrics")
    print(f"cores visible: {os.cpu_count()}, load average: "
          f"{', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"full report wall time: median {walls[best]:.2f} s (runs: "
          f"{', '.join(f'{w:.2f}' for w in walls)}); CPU time {cpus[best]:.2f} s")
    for name, seconds in steps[best].items():
        print(f"  {name:28s} {seconds:6.2f} s")
    print(f"target < 30 s: {'met' if walls[best] < 30 else 'NOT met'}")


if __name__ == "__main__":
    main()
