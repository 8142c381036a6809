"""Speed of the calibration fit: 100k Adam steps of the upstream objective on a feature cache.

Goal (issue #7): 100k steps on a 100-video dataset in under a minute on CPU. Prints, for
16/64 patches and N = 131/1027 channels, the wall time of the vectorised fit (one split, and
ten splits fitted together as in the repeated validation), and the per-step cost of the plain
torch autograd + torch.optim.Adam loop it replaces (measured on a few hundred steps).

    .venv/bin/python benchmarks/bench_calibration.py [--steps 100000] [--threads 1]

The synthetic cache mimics real ones: each video's distortion has a channel profile and a
per-patch intensity (log-normal across patches), so a few patches dominate each video.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import torch

from cgvqm_core.calibration.fitting import FitConfig, fit
from cgvqm_core.calibration.objective import calibration_loss


def synthetic_cache(V: int, P: int, N: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    profiles = rng.gamma(0.5, 1.0, (4, N))
    family = rng.integers(0, 4, V)
    severity = rng.uniform(0.2, 3.0, V)
    intensity = np.exp(rng.normal(0, 1.0, (V, P))) * severity[:, None]
    M = intensity[:, :, None] * profiles[family][:, None, :] * rng.gamma(4, 0.25, (V, P, N))
    y = 100 - 10 * severity + rng.normal(0, 3, V)
    return M.astype(np.float32), y


def torch_loop_seconds_per_step(M: np.ndarray, y: np.ndarray, steps: int) -> float:
    Mt, yt = torch.tensor(M), torch.tensor(y, dtype=torch.float32)
    counts = torch.full((M.shape[0],), M.shape[1])
    groups = torch.zeros(M.shape[0], dtype=torch.long)
    omega = torch.rand(M.shape[2], generator=torch.Generator().manual_seed(0))
    omega = (omega / omega.sum()).requires_grad_()
    alpha = torch.tensor(1000.0, requires_grad=True)
    opt = torch.optim.Adam([{"params": [omega], "lr": 1e-6}, {"params": [alpha], "lr": 1.0}])
    t0 = time.perf_counter()
    for _ in range(steps):
        opt.zero_grad(set_to_none=True)
        calibration_loss(Mt, counts, yt, groups, omega, alpha).backward()
        opt.step()
    return (time.perf_counter() - t0) / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=100_000)
    ap.add_argument("--videos", type=int, default=100)
    ap.add_argument("--threads", type=int, default=1,
                    help="threads of torch and of numpy's BLAS (default 1)")
    ap.add_argument("--torch-steps", type=int, default=300)
    ap.add_argument("--splits", type=int, default=10)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    try:  # numpy's BLAS threads (threadpoolctl comes with scikit-learn, via pingouin)
        from threadpoolctl import threadpool_limits

        threadpool_limits(args.threads)
        blas = f"BLAS threads limited to {args.threads}"
    except ImportError:
        blas = "BLAS threads: numpy's default (threadpoolctl not installed)"
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"torch {torch.__version__} ({args.threads} threads), numpy {np.__version__}, {blas}")
    print(f"# {args.videos} videos, {args.steps} steps; times in seconds")
    many = f"fit {args.splits} splits"
    print(f"{'patches':>7} {'N':>5} {'fit 1 split':>12} {many:>14} "
          f"{'re-evals/step':>13} {'torch loop (extrapolated)':>26}")
    for P, N in ((16, 131), (64, 131), (16, 1027), (64, 1027)):
        M, y = synthetic_cache(args.videos, P, N)
        counts = np.full(args.videos, P)
        groups = np.zeros(args.videos, dtype=np.int64)
        cfg = FitConfig(steps=args.steps, show_progress=False)
        t0 = time.perf_counter()
        one = fit(M, counts, y, groups, np.ones((1, args.videos), bool), config=cfg)
        t_one = time.perf_counter() - t0
        rng = np.random.default_rng(1)
        train = rng.random((args.splits, args.videos)) < 0.5
        t0 = time.perf_counter()
        fit(M, counts, y, groups, train, config=cfg)
        t_many = time.perf_counter() - t0
        per_step = torch_loop_seconds_per_step(M, y, args.torch_steps)
        print(f"{P:>7} {N:>5} {t_one:>12.1f} {t_many:>14.1f} "
              f"{one.refreshes / args.steps:>13.2f} {per_step * args.steps:>26.1f}", flush=True)


if __name__ == "__main__":
    main()
