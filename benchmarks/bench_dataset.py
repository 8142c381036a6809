"""Dataset-level throughput: a paper-shaped set scored the upstream way and the batched way.

The set: --refs references x --levels distorted versions each (default 3 x 4 = 12 pairs of
30x512x512 at 30 fps: 16 patches per pair), generated in memory, so no decoding is timed on
either side. Scored, back to back in one run on one machine:

- upstream as its users run it: every pair on its own, one call per pair, through
  upstream_as_run.py (a same-machine stand-in that follows the authors' run_cgvqm: host
  float32 videos, per-patch copies, batch 1, default layout, batch norm unfolded, error map
  copied back per patch; PyTorch's default TF32 convolutions on CUDA);
- batched, the way ``cgvqm batch`` runs a manifest: each reference with its tests
  (``score_many``: the reference goes through the network once per patch, test + reference
  batched, channels-last, batch norm folded, no error map), in fp32 and in each further
  precision the device offers (bf16 on CPUs with AMX/AVX512-BF16; tf32, bf16, fp16 on CUDA).

Printed: wall time of the set, seconds per pair, pairs per minute, the ratio to the
upstream-style run, and max |dq| against it over the set (max and mean pooling).
Targets: on CPU fp32 >= 2x the upstream run, bf16 >= 5x; on CUDA the default (auto: tf32)
>= 2.5x at max |dq| <= 1e-3. (The measurements below, before 2026-11-25, were against the
earlier stand-in, "upstream-style": the same network configuration from in-memory uint8
clips, without the per-patch float copies; on a CPU both take the same time.)

The backbone is random (seed 0; speed does not depend on its values); the weights are the
published ones when a copy is at hand (see bench_cgvqm.weights_for), else uniform.

Measured (raw output in benchmarks/results/):
- NVIDIA H100 (bench_dataset_cuda.txt; upstream-style with PyTorch's default TF32):
  CGVQM-2 0.13 s/pair upstream-style; batched fp32 x1.39, tf32 x2.90, bf16 x3.32, fp16
  x3.29; CGVQM-5 0.22 s/pair; x1.31, x3.19, x3.10, x3.95.
- Intel Xeon with AMX-BF16, 16 cores, idle (bench_dataset_xeon_amx.txt): CGVQM-2 6.93
  s/pair upstream-style; batched fp32 2.42 s/pair = x2.87, bf16 0.81 s/pair = x8.53 (max
  |dq| 0.038). (The CGVQM-5 half of that run hit its time limit.)
- 2 cores of an AMD EPYC with AVX512-BF16, UNDER LOAD, load average 2-4 (bench_dataset_cpu.txt):
  CGVQM-2 16.4 s/pair upstream-style; batched fp32 8.24 s/pair = x1.99 (target x2: missed by
  a hair), bf16 4.44 s/pair = x3.69 (target x5: MISSED; max |dq| 0.038).

    python benchmarks/bench_dataset.py                          # 3 x 4 x 30x512x512, CGVQM-2
    python benchmarks/bench_dataset.py --size 128 --refs 2 --levels 2      # quick look
    python benchmarks/bench_dataset.py --device cuda --variants cgvqm-2,cgvqm-5
"""

from __future__ import annotations

import os

os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")  # as cgvqm_core does, before torch loads

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cgvqm import (
    default_precisions,
    header,
    sync,
    usable_precisions,
    video,
    weights_for,
)
from upstream_as_run import UpstreamAsRun

from cgvqm_core import CGVQM
from cgvqm_core.hub import random_backbone

NOISE_LEVELS = (2.0, 4.0, 8.0, 16.0, 24.0, 32.0)


def distorted(ref: np.ndarray, level: int, seed: int) -> np.ndarray:
    """Level ``level`` of a noise + shift distortion (stronger with the level)."""
    rng = np.random.default_rng(seed)
    sigma = NOISE_LEVELS[level % len(NOISE_LEVELS)]
    out = np.roll(ref, level % 3, axis=2).astype(np.float32)
    out += rng.normal(0, sigma, ref.shape[1:]).astype(np.float32)
    return np.clip(out, 0, 255).astype(np.uint8)


def dataset(n_refs: int, n_levels: int, frames: int, size: int):
    for r in range(n_refs):
        ref = video(100 + r, frames, size, size)
        yield ref, [distorted(ref, lv, 1000 * r + lv) for lv in range(n_levels)]


def run_upstream(up: UpstreamAsRun, data, device: str) -> tuple[float, np.ndarray]:
    """Every pair on its own through the stand-in for the authors' run_cgvqm."""
    sync(device)
    t0 = time.perf_counter()
    q = [(r.q_max, r.q_mean) for ref, tests in data for r in (up.score(ref, t) for t in tests)]
    sync(device)
    return time.perf_counter() - t0, np.array(q)


def run_batched(metric: CGVQM, data, device: str, group: int) -> tuple[float, np.ndarray]:
    sync(device)
    t0 = time.perf_counter()
    q = []
    for ref, tests in data:
        for i in range(0, len(tests), group):
            q += [(res.quality("max"), res.quality("mean"))
                  for res in metric.score_many(ref, tests[i: i + group])]
    sync(device)
    return time.perf_counter() - t0, np.array(q)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--refs", type=int, default=3)
    ap.add_argument("--levels", type=int, default=4)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--variants", default="cgvqm-2")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--precisions", help="comma-separated (default as bench_cgvqm.py)")
    ap.add_argument("--group-size", type=int, default=4,
                    help="test videos per score_many call (cgvqm batch's default 4)")
    ap.add_argument("--batch-size", type=int,
                    help="videos per network pass in the batched run (default: the "
                         "device's, 2 on a CPU, 16 on CUDA)")
    ap.add_argument("--threads", type=int)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    cuda = args.device.startswith("cuda")
    fig: dict = {"machine": header(args.device)}
    wanted = args.precisions.split(",") if args.precisions else default_precisions(args.device)
    precs = usable_precisions(wanted, args.device)
    n = args.refs * args.levels
    T, S = args.frames, args.size
    print(f"set: {args.refs} references x {args.levels} levels = {n} pairs of {T}x{S}x{S} "
          f"at 30 fps; precisions {', '.join(precs)}")
    data = list(dataset(args.refs, args.levels, T, S))
    bb = random_backbone(0)
    fig["backbone_sha256"], fig["set"] = bb.sha256, {"refs": args.refs, "levels": args.levels,
                                                     "frames": T, "size": S}
    targets = ({"auto": (2.5, 1e-3)} if cuda else {"fp32": (2.0, None), "bf16": (5.0, None)})
    for v in args.variants.split(","):
        w = weights_for(v)
        up_m = UpstreamAsRun(bb, w, device=args.device)
        up_m.score(data[0][0][:2], data[0][1][0][:2])  # warm-up
        up_s, up_q = run_upstream(up_m, data, args.device)
        print(f"\n{v} (weights {w.kind}):\n  upstream as its users run it (one call per pair, "
              f"benchmarks/upstream_as_run.py): {up_s:.1f} s = {up_s / n:.2f} s/pair = "
              f"{60 * n / up_s:.1f} pairs/min")
        rows = {"upstream_as_run": {"seconds": up_s, "s_per_pair": up_s / n}}
        for p in ["auto", *precs] if cuda else precs:
            m = CGVQM(v, weights=w, backbone=bb, device=args.device, precision=p,
                      batch_size=args.batch_size)
            if cuda:  # the shapes of the run: cuDNN's algorithm search happens once
                run_batched(m, data[:1], args.device, args.group_size)
            else:
                m.score(data[0][0][:2], data[0][1][0][:2])  # warm-up
            s, q = run_batched(m, data, args.device, args.group_size)
            dq = np.abs(q - up_q).max(axis=0)
            rows[p] = {"seconds": s, "s_per_pair": s / n, "x_upstream": up_s / s,
                       "max_dq_vs_upstream": {"max_pool": float(dq[0]),
                                              "mean_pool": float(dq[1])}}
            tgt = ""
            if p in targets:
                x_t, dq_t = targets[p]
                ok = up_s / s >= x_t and (dq_t is None or float(dq.max()) <= dq_t)
                tgt = (f" (target x{x_t:g}" + (f" at |dq| <= {dq_t:g}" if dq_t else "")
                       + f": {'met' if ok else 'MISSED'})")
            label = f"{p} (the default: {m.net.precision})" if p == "auto" else p
            print(f"  batched (reference reuse, group {args.group_size}) {label}: {s:.1f} s = "
                  f"{s / n:.2f} s/pair = {60 * n / s:.1f} pairs/min: x{up_s / s:.2f} against "
                  f"upstream as run{tgt}; max |dq| {dq[0]:.2e} (max pooling), {dq[1]:.2e} "
                  "(mean pooling)")
        fig[v] = rows
    load = os.getloadavg()
    print(f"\nload average at the end: {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}")
    fig["load_average_end"] = load
    if args.json:
        args.json.write_text(json.dumps(fig, indent=1))
        print(f"figures written to {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
