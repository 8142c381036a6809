"""``cgvqm batch`` locally and on Ray (1 and 2 workers), and a scaling model from the figures.

The set: --refs references x --levels distorted versions (default 3 x 4 = 12 pairs of
30x256x256 at 30 fps), written as lossless video files with a checksummed manifest, since
Ray units carry paths and sha256s and every worker decodes its own files. Scored with
CGVQM-2 (random backbone seed 0, uniform weights: speed does not depend on their values):

- local: ``score_manifest`` in this process, one torch thread (``cgvqm batch --threads 1``);
- Ray with 1 and with 2 workers: a fresh local Ray instance with that many CPUs, one CPU
  (and so one torch thread) per task, ``cgvqm batch --ray``'s code path.

Printed: wall time of each run (Ray's start-up apart), each unit's seconds measured inside
its task (and by the local run), Ray's overhead per unit (the wall time beyond the ideal
one, the units' own seconds spread over the workers, per unit on the busiest worker:
scheduling, transfers, the workers' imports and metric set-up), whether the scores equal
the local run's, and a model of a larger set (--dataset-refs x --dataset-tests) on N = 1, 2,
4, 8 devices: the measured CPU unit time scaled to that unit size, and the H100 unit time
from the README's measured pairs per minute (4 tests per reference, per precision) when it
has them, each plus the overhead measured here. A unit is one reference, so N devices take
ceil(references / N) unit times.

    python benchmarks/bench_ray.py                              # 3 x 4 x 30x256x256
    python benchmarks/bench_ray.py --size 128 --frames 16       # quick look
    python benchmarks/bench_ray.py --dataset-refs 60 --dataset-tests 10 --json out.json
"""

from __future__ import annotations

import os

os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")  # as cgvqm_core does, before torch loads
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

import argparse
import csv
import json
import math
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cgvqm import header
from bench_dataset import dataset

import cgvqm_core.batch as batch
from cgvqm_core.metrics import MetricOptions
from stimuli_manifests import fill_checksums, load_manifest, save_manifest, write_video

README = Path(__file__).resolve().parents[1] / "README.md"
FPS = 30


def write_set(root: Path, refs: int, levels: int, frames: int, size: int) -> Path:
    videos = root / "videos"
    doc: dict = {"format": "cgvq-manifest/1", "study_id": "bench-ray", "root": "videos",
                 "references": [], "conditions": []}
    for r, (ref, tests) in enumerate(dataset(refs, levels, frames, size)):
        write_video(videos / f"ref{r}.mkv", ref, FPS)
        doc["references"].append({"path": f"ref{r}.mkv", "scene": f"scene{r}"})
        for lv, t in enumerate(tests, start=1):
            write_video(videos / f"ref{r}_l{lv}.mkv", t, FPS)
            doc["conditions"].append({"reference": f"SRC{r + 1:02d}",
                                      "path": f"ref{r}_l{lv}.mkv", "method": "noise",
                                      "level": lv})
    path = root / "manifest.json"
    path.write_text(json.dumps(doc))
    save_manifest(fill_checksums(load_manifest(path)), path)
    return path


def scores(path: Path) -> dict[str, str]:
    with path.open(newline="", encoding="utf-8") as fh:
        return {r["key"]: r["score"] for r in csv.DictReader(fh)}


def run_local(manifest: Path, out: Path, options: MetricOptions) -> tuple[float, list[float]]:
    """score_manifest as `cgvqm batch` runs it, timing each unit as it goes."""
    unit_s: list[float] = []
    run_unit = batch.run_unit

    def timed(*a, **kw):
        t0 = time.perf_counter()
        rows = run_unit(*a, **kw)
        unit_s.append(time.perf_counter() - t0)
        return rows

    batch.run_unit = timed
    try:
        t0 = time.perf_counter()
        batch.score_manifest(manifest, out, ["cgvqm-2"], options, progress=False)
        return time.perf_counter() - t0, unit_s
    finally:
        batch.run_unit = run_unit


def run_ray(manifest: Path, out: Path, options: MetricOptions, workers: int) -> dict:
    import ray

    from cgvqm_core import distributed
    from cgvqm_core.ray_options import RaySettings

    t0 = time.perf_counter()
    ray.init(address="local", num_cpus=workers, include_dashboard=False,
             logging_level="WARNING")
    start = time.perf_counter() - t0
    try:
        t0 = time.perf_counter()
        s = distributed.score_manifest(manifest, out, ["cgvqm-2"], options,
                                       RaySettings(cpus_per_unit=1), progress=False)
        wall = time.perf_counter() - t0
    finally:
        ray.shutdown()
    if s.failed:
        raise SystemExit(f"Ray run failed: {s.failed}")
    return {"start_s": start, "wall_s": wall, "unit_s": list(s.unit_seconds.values())}


def makespan(unit_s: list[float], workers: int) -> float:
    """The wall time the units' own seconds allow on ``workers`` (longest first, each to the
    least busy worker): what a run without any overhead would take."""
    busy = [0.0] * workers
    for u in sorted(unit_s, reverse=True):
        busy[busy.index(min(busy))] += u
    return max(busy)


def readme_gpu_rates(variant: str) -> dict[str, float]:
    """Pairs per minute with 4 tests per reference, per precision, from the README's H100
    table (empty when the README has none)."""
    if not README.is_file():
        return {}
    lines = README.read_text(encoding="utf-8").splitlines()
    cols: list[str] = []
    for line in lines:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) > 1 and cells[0] == "" and all(c in ("fp32", "tf32", "bf16", "fp16")
                                                     for c in cells[1:]):
            cols = cells[1:]
        if cols and line.startswith(f"| {variant.upper()}") and "pairs per minute" in line:
            rates = [re.findall(r"[\d.]+", c) for c in cells[1:]]
            return {p: float(r[-1]) for p, r in zip(cols, rates, strict=False) if r}
    return {}


def model(unit_s: float, overhead_s: float, refs: int, gpus: list[int]) -> dict:
    per_unit = unit_s + overhead_s
    return {"unit_s": per_unit, "units_per_hour": 3600 / per_unit,
            "wall_s": {n: math.ceil(refs / n) * per_unit for n in gpus}}


def fmt_h(s: float) -> str:
    return f"{s / 3600:.2f} h" if s >= 3600 else f"{s / 60:.1f} min"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--refs", type=int, default=3)
    ap.add_argument("--levels", type=int, default=4)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--workers", default="1,2", help="Ray runs (CPUs of the local instance)")
    ap.add_argument("--dataset-refs", type=int, default=60)
    ap.add_argument("--dataset-tests", type=int, default=10)
    ap.add_argument("--gpus", default="1,2,4,8")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    torch.set_num_threads(1)
    fig: dict = {"machine": header("cpu")}
    n_pairs = args.refs * args.levels
    print(f"set: {args.refs} references x {args.levels} levels = {n_pairs} pairs of "
          f"{args.frames}x{args.size}x{args.size}, CGVQM-2 fp32, 1 torch thread per unit")
    options = MetricOptions(random_backbone=0, weights="uniform")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        manifest = write_set(root, args.refs, args.levels, args.frames, args.size)
        local_s, local_units = run_local(manifest, root / "local.csv", options)
        print(f"local cgvqm batch: {local_s:.1f} s; units "
              f"{', '.join(f'{u:.2f}' for u in local_units)} s")
        fig["local"] = {"wall_s": local_s, "unit_s": local_units}
        expected = scores(root / "local.csv")
        for w in (int(x) for x in args.workers.split(",")):
            out = root / f"ray{w}.csv"
            r = run_ray(manifest, out, options, w)
            ideal = makespan(r["unit_s"], w)
            over = (r["wall_s"] - ideal) / math.ceil(len(r["unit_s"]) / w)
            r["ideal_makespan_s"] = ideal
            same = scores(out) == expected
            r.update({"overhead_per_unit_s": over, "identical_to_local": same})
            print(f"ray, {w} worker(s): {r['wall_s']:.1f} s (+ {r['start_s']:.1f} s to start "
                  f"Ray) = x{local_s / r['wall_s']:.2f} against local; units "
                  f"{', '.join(f'{u:.2f}' for u in r['unit_s'])} s inside the task (ideal "
                  f"wall {ideal:.1f} s); overhead {over:.2f} s per unit; scores identical to "
                  f"local: {'yes' if same else 'NO'}")
            fig[f"ray_{w}"] = r
    one = fig.get("ray_1", next(v for k, v in fig.items() if k.startswith("ray_")))
    unit_cpu = statistics.median(one["unit_s"])
    overhead = max(0.0, one["overhead_per_unit_s"])
    gpus = [int(x) for x in args.gpus.split(",")]
    R, T = args.dataset_refs, args.dataset_tests
    print(f"\nscaling model: {R} references x {T} tests = {R * T} videos, one unit = one "
          f"reference with {T} tests; Ray overhead {overhead:.2f} s per unit (measured above)")
    per_test_cpu = unit_cpu / args.levels
    rows = {f"cpu core, {args.frames}x{args.size}x{args.size} (measured)":
            model(per_test_cpu * T, overhead, R, gpus)}
    rates = readme_gpu_rates("cgvqm-2")
    for p, ppm in rates.items():
        rows[f"H100 {p}, 3 s 1024x1024 (README)"] = model(60 / ppm * T, overhead, R, gpus)
    if not rates:
        print("(no GPU figures in the README: the model uses the measured CPU time only)")
    print(f"{'device, clip':<40} {'s/unit':>8} {'units/h':>8} " +
          " ".join(f"{f'N={n}':>10}" for n in gpus))
    for name, m in rows.items():
        print(f"{name:<40} {m['unit_s']:>8.1f} {m['units_per_hour']:>8.1f} " +
              " ".join(f"{fmt_h(m['wall_s'][n]):>10}" for n in gpus))
    fig["model"] = {"refs": R, "tests": T, "overhead_s": overhead, "rows": rows}
    load = os.getloadavg()
    print(f"\nload average at the end: {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}")
    if args.json:
        args.json.write_text(json.dumps(fig, indent=1, default=str))
        print(f"figures written to {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
