"""Time per pair and peak memory of every available registry metric, on one 30x512x512 pair.

Each metric runs in its own process (peak RSS is a per-process high-water mark): the process
builds the metric, scores one test video against its reference from lossless files through
the streaming engine, and reports wall seconds and peak RSS (``ru_maxrss``). The baseline row
``(decode only)`` streams the same pair through the engine with no metric work, so the
difference is what the metric adds. For scale: the whole 30x512x512 video as float64 RGB
would be 189 MB; streamed metrics hold a chunk of frames, never the video.

CGVQM runs with a seeded random backbone and uniform weights (same cost as the real ones).
Usage: python benchmarks/bench_metrics.py [--frames 30] [--size 512] [--metrics all]
[--threads N]. Figures depend on the machine's load: report whether it was idle.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def make_pair(folder: Path, frames: int, size: int) -> tuple[Path, Path]:
    from stimuli_manifests import write_video

    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:size, 0:size].astype(np.float32)
    ref = []
    for t in range(frames):
        base = 128 + 60 * np.sin((x + 3 * t) / 23.0) * np.cos((y - 2 * t) / 31.0)
        img = np.stack([base, base * 0.8 + 20, 255 - base], -1)
        ref.append(np.clip(img + rng.normal(0, 4, img.shape), 0, 255).astype(np.uint8))
    test = [np.clip(f + rng.normal(0, 8, f.shape), 0, 255).astype(np.uint8) for f in ref]
    return (write_video(folder / "ref.mkv", ref, 30), write_video(folder / "test.mkv", test, 30))


def one(name: str, ref: str, test: str, threads: int | None) -> dict:
    import torch

    if threads:
        torch.set_num_threads(threads)
    from cgvqm_core.metrics import MetricOptions, build_scorers, score_reference
    from cgvqm_core.metrics.engine import frame_chunks, open_pair_sources

    t0 = time.perf_counter()
    if name == "(decode only)":
        rsrc, tsrcs, geom = open_pair_sources(ref, [test])
        for _ in frame_chunks(rsrc, tsrcs, geom, 4):
            pass
        build = 0.0
    else:
        (s,) = build_scorers([name], MetricOptions(random_backbone=0, weights="uniform"))
        build = time.perf_counter() - t0
        t0 = time.perf_counter()
        score_reference(ref, [test], [s])
    seconds = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2  # KiB -> GiB
    return {"metric": name, "seconds": seconds, "build_seconds": build, "peak_rss_gb": rss}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--metrics", default="all")
    p.add_argument("--threads", type=int)
    p.add_argument("--one", help=argparse.SUPPRESS)
    p.add_argument("--pair", nargs=2, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.one:
        print(json.dumps(one(args.one, *args.pair, args.threads)))
        return
    from cgvqm_core.metrics import parse_metric_list

    names = ["(decode only)", *parse_metric_list(args.metrics)]
    print(f"one {args.frames}x{args.size}x{args.size} pair per metric, each in its own "
          "process (seconds exclude building the metric)")
    print(f"{'metric':<15} {'s/pair':>8} {'build s':>8} {'peak RSS GB':>12}")
    with tempfile.TemporaryDirectory() as tmp:
        ref, test = make_pair(Path(tmp), args.frames, args.size)
        for name in names:
            cmd = [sys.executable, __file__, "--one", name, "--pair", str(ref), str(test)]
            if args.threads:
                cmd += ["--threads", str(args.threads)]
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode:
                print(f"{name:<15} failed: {res.stderr.strip().splitlines()[-1:]}")
                continue
            rec = json.loads(res.stdout.strip().splitlines()[-1])
            print(f"{name:<15} {rec['seconds']:8.2f} {rec['build_seconds']:8.2f} "
                  f"{rec['peak_rss_gb']:12.2f}", flush=True)


if __name__ == "__main__":
    main()
