"""Speed, memory and precision of cgvqm_core on this machine (prints figures; not a test).

What it measures (CPU unless --device cuda; every precision of --precisions, fp32 first):

1. the conv3d peak: layer1's 64->64 3x3x3 convolution at the shape it runs in CGVQM
   (2 x 64 x T x S/8 x S/8), default and channels-last-3d layouts, best of both, per dtype;
2. seconds per test/reference pair of T x S x S frames (default 30 x 512 x 512: 16 patches)
   for CGVQM-2 and CGVQM-5 in each precision, the FLOP count of that work (convolutions,
   multiply-adds x 2, counted from the network's shapes), the achieved GFLOP/s as a fraction
   of the peak, and |dq| of each precision against fp32 (max and mean pooling; published
   omega/alpha when found, else uniform weights);
3. the speed-up of each optimisation on CGVQM-2: channels-last layout, batch norm folding,
   batching test + reference, and reference reuse (four test videos sharing one reference),
   and the single-pair and reference-reuse speed of every precision (and, on CUDA, of the
   default ``auto``) against the authors' code as its users run it (upstream_as_run.py, a
   same-machine stand-in that follows run_cgvqm's data flow), with |dq| against it; on CUDA
   also the four tf32 configurations (batch norm folded or not, cuDNN benchmark on or off);
4. on CUDA: fp32 parity with the CPU on the same pair (TF32 off; target |dq| <= 1e-4),
   pairs per minute for 3 s 1024x1024 stimuli (single pair, four tests per reference, and a
   batch-size sweep with peak GPU memory; target 350 for CGVQM-2 in bf16/fp16), and the
   CGVQM-2 : CGVQM-5 time ratio on one 32x512x512 patch pair (the paper: CGVQM-2 is 27 %
   faster than CGVQM-5 there, on an A100);
4b. where the time goes when scoring from H.264 files (cgvqm_core.stage_clock): decode,
   wait, copy, backbone, pooling, idle, with decoding inline and ahead in a thread
   (T x S x S on a CPU, 3 s 1024x1024 on CUDA); ``--trace DIR`` adds a torch.profiler trace;
5. peak RSS of a separate process scoring a 1080p30 pair streamed from lossless files, for
   1 s and 10 s (target: under 4 GB), so you can see that memory does not grow with the
   video's length. The 10 s pair is 160 patches of 30x270x480: about 30 min on 2 cores.

The backbone is random (seed 0, the same on every machine): speed does not depend on the
weights, and the drift is a proxy (bench_precision.py measures it over whole study sets).
On a shared machine numbers are noisy: report the load printed along with them.

Measured (raw output in benchmarks/results/, random backbone seed 0, published omega/alpha):
- NVIDIA H100 80GB, torch 2.11+cu130 (bench_cgvqm_cuda.txt): CGVQM-2 per 30x512x512 pair
  fp32 0.16 s, tf32 0.08, bf16 0.06, fp16 0.07 (CGVQM-5: 0.26, 0.10, 0.08, 0.08); fp32 on
  CUDA vs CPU |dq| <= 4.6e-6; 3 s 1024x1024 CGVQM-2 pairs per minute 34 / 77 / 83 / 92
  (single pair; 58 / 123 / 139 / 146 with four tests per reference); CGVQM-2 vs CGVQM-5 on a
  32x512x512 patch pair: 68 % faster in fp32, 30 % in tf32 (the paper: 27 % on an A100,
  where PyTorch's default is TF32), 21 % bf16, 16 % fp16.
- Intel Xeon with AMX-BF16, 16 cores, idle, torch 2.11 (bench_cgvqm_xeon_amx.txt): CGVQM-2
  fp32 3.74 s/pair (82 % of the conv3d rate), bf16 1.30 s (|dq| 0.005); against the
  upstream-style run (5.73 s) fp32 x1.47, bf16 x4.53 single pair; x2.36 / x6.91 per pair with
  four tests per reference.
- 2 cores of an AMD EPYC with AVX512-BF16 (no AMX), torch 2.13, UNDER LOAD from other
  engineers' jobs, load average 2-5 (bench_cgvqm_cpu.txt): CGVQM-2 per 30x512x512 pair
  fp32 9.96 s (80 % of the conv3d rate), bf16 6.53 s (x1.52, |dq| 0.005);
  against the upstream-style run (16.8 s) fp32 x1.68,
  bf16 x2.82 single pair (target x3: MISSED under load), x2.51 / x3.66 with four tests per
  reference. bf16 convolutions run only 2x faster than fp32 there (930 vs 462 GFLOP/s).

    python benchmarks/bench_cgvqm.py                       # full run (~45 min on 2 cores)
    python benchmarks/bench_cgvqm.py --rss-only            # only the 1080p memory figures
    python benchmarks/bench_cgvqm.py --size 256 --frames 16 --rss-seconds 0   # quick look
    python benchmarks/bench_cgvqm.py --device cuda --json cuda.json          # a GPU
    python benchmarks/bench_cgvqm.py --breakdown-only --trace /tmp/trace     # time split
"""

from __future__ import annotations

import os

os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")  # as cgvqm_core does, before torch loads

import argparse
import contextlib
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from cgvqm_core import CGVQM, host_memory
from cgvqm_core.errors import CGVQMError
from cgvqm_core.features import FeatureNet
from cgvqm_core.host_memory import retained
from cgvqm_core.hub import random_backbone
from cgvqm_core.metric import CGVQMResult
from cgvqm_core.patch_scorer import PatchScorer
from cgvqm_core.precision import DTYPES, cpu_bf16, cpu_name
from cgvqm_core.stage_clock import StageClock
from cgvqm_core.weights import resolve_weights, uniform_weights

sys.path.insert(0, str(Path(__file__).resolve().parent))
from upstream_as_run import UpstreamAsRun

SPEC_TFLOP = {"cgvqm-2": 3.7, "cgvqm-5": 6.5}  # per 30x512x512 pair, from the spec
SHARED_WEIGHTS = Path(__file__).resolve().parents[2] / "shared" / "data" / "cgvqm_upstream"
PAPER_SPEEDUP = 1.27  # CGVQM-2 vs CGVQM-5 on 32x512x512 patches, A100 (the paper)


def weights_for(variant: str, wdir: str | None = None):
    """The published omega/alpha when a copy is at hand (drift needs real weights), else
    uniform weights (speed does not depend on them)."""
    for d in [wdir, os.environ.get("CGVQM_WEIGHTS_DIR"), SHARED_WEIGHTS]:
        if d and (Path(d) / f"{variant}.pickle").is_file():
            return resolve_weights(Path(d) / f"{variant}.pickle")
    try:
        return resolve_weights(None, variant, allow_download=False)
    except CGVQMError:
        return uniform_weights(variant)


def video(seed: int, frames: int, height: int, width: int) -> np.ndarray:
    """A textured moving pattern (generated, so nothing needs downloading)."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames, dtype=np.float32)[:, None, None, None]
    y = np.arange(height, dtype=np.float32)[None, :, None, None]
    x = np.arange(width, dtype=np.float32)[None, None, :, None]
    base = 128 + 70 * np.sin(0.05 * x + 0.03 * y + 0.2 * t + rng.uniform(0, 6, (1, 1, 1, 3)))
    base = base + rng.normal(0, 10, (1, height, width, 3)).astype(np.float32)
    return np.clip(base, 0, 255).astype(np.uint8)


def noisy(v: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(v + rng.normal(0, 8, v.shape[1:]).astype(np.float32), 0, 255).astype(np.uint8)


def sync(device: str) -> None:
    if str(device).startswith("cuda"):
        torch.cuda.synchronize()


def conv_peak(frames: int, size: int, device: str, repeats: int,
              dtype: torch.dtype = torch.float32) -> dict[str, float]:
    """GFLOP/s of layer1's convolution, both layouts (TF32 off for fp32 on CUDA; cuDNN's
    benchmark mode on, as scoring runs, so the peak is that of the fastest algorithm).

    On a CPU it runs with freed memory kept for reuse, as scoring does
    (:mod:`cgvqm_core.host_memory`): the rate of the convolution itself, without the page
    faults of a fresh output every call (9 % of it on a 2-core EPYC without huge pages)."""
    x = torch.randn(2, 64, frames, size // 8, size // 8, device=device).to(dtype)
    w = torch.randn(64, 64, 3, 3, 3, device=device).to(dtype)
    b = torch.randn(64, device=device).to(dtype)
    flop = 2 * x.numel() * 64 * 27
    out = {}
    layouts = (("default", torch.contiguous_format), ("channels_last", torch.channels_last_3d))
    saved = torch.backends.cudnn.allow_tf32, torch.backends.cudnn.benchmark
    # cuDNN's algorithm search on, as CGVQM runs (the warm-up calls below pay for it)
    torch.backends.cudnn.allow_tf32, torch.backends.cudnn.benchmark = False, True
    try:
        for name, fmt in layouts:
            xx, ww = x.contiguous(memory_format=fmt), w.contiguous(memory_format=fmt)
            with torch.inference_mode(), retained(not str(device).startswith("cuda")):
                for _ in range(2):
                    F.conv3d(xx, ww, b, padding=1)
                sync(device)
                best = float("inf")
                for _ in range(repeats):
                    t0 = time.perf_counter()
                    F.conv3d(xx, ww, b, padding=1)
                    sync(device)
                    best = min(best, time.perf_counter() - t0)
            out[name] = flop / best / 1e9
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cudnn.benchmark = saved
    return out


def conv_peaks(frames: int, size: int, device: str, repeats: int,
               precision: str) -> dict[str, float]:
    """:func:`conv_peak` for a precision name; tf32 is measured with TF32 on (one layout)."""
    if precision != "tf32":
        return conv_peak(frames, size, device, repeats, DTYPES[precision])
    saved = torch.backends.cudnn.allow_tf32, torch.backends.cudnn.benchmark
    torch.backends.cudnn.allow_tf32, torch.backends.cudnn.benchmark = True, True
    try:
        x = torch.randn(2, 64, frames, size // 8, size // 8, device=device)
        wt = torch.randn(64, 64, 3, 3, 3, device=device)
        F.conv3d(x, wt, padding=1)
        sec = timed(lambda: F.conv3d(x, wt, padding=1), max(5, repeats), device)
        return {"default": 2 * x.numel() * 64 * 27 / sec / 1e9}
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cudnn.benchmark = saved


def conv_peak_of(frames: int, size: int, device: str, repeats: int, precision: str) -> float:
    """The best layout's conv3d rate for ``precision`` (GFLOP/s)."""
    return max(conv_peaks(frames, size, device, repeats, precision).values())


def conv_flops(net: FeatureNet, frames: int, ph: int, pw: int, batch: int) -> float:
    """Multiply-adds x 2 of every convolution for one patch batch (shapes on 'meta')."""
    total = 0.0

    def hook(mod: torch.nn.Conv3d, inp: tuple[torch.Tensor], out: torch.Tensor) -> None:
        nonlocal total
        k = mod.kernel_size[0] * mod.kernel_size[1] * mod.kernel_size[2]
        total += 2.0 * out.numel() * (mod.in_channels // mod.groups) * k

    meta = net.model.to("meta")
    hooks = [m.register_forward_hook(hook) for m in meta.modules()
             if isinstance(m, torch.nn.Conv3d)]
    with torch.no_grad():
        list(meta.levels(torch.empty(batch, 3, frames, ph, pw, device="meta"), net.n_levels))
    for h in hooks:
        h.remove()
    return total


def timed(fn, repeats: int, device: str = "cpu") -> float:
    """Best wall time of ``repeats`` calls (the device synchronised before the clock stops).

    On CUDA one untimed call comes first: cuDNN's benchmark mode searches its algorithms at
    the first pass of each new shape, which a run pays once, not per pair."""
    if str(device).startswith("cuda"):
        fn()
    best = float("inf")
    for _ in range(repeats):
        sync(device)
        t0 = time.perf_counter()
        fn()
        sync(device)
        best = min(best, time.perf_counter() - t0)
    return best


def rss_child(ref: str, test: str, variant: str, device: str) -> None:
    m = CGVQM(variant, weights=uniform_weights(variant), backbone=random_backbone(0),
              device=device)
    res = m.score(ref, test)
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"q": res.q, "patches": res.n_patches, "seconds": res.seconds,
                      "peak_rss_gb": peak_kb / 1024**2}))


def memory_child(args: argparse.Namespace, mode: str) -> None:
    """One CGVQM-2 pair in this fresh process, with freed memory kept (``keep``) or with
    glibc's own behaviour from the start (``off``: its state cannot be restored in-process
    once changed). Prints seconds and minor page faults."""
    ref = video(1, args.frames, args.size, args.size)
    test = noisy(ref, 10)
    m = CGVQM("cgvqm-2", weights=weights_for("cgvqm-2"), backbone=random_backbone(0),
              device="cpu")
    with host_memory.disabled() if mode == "off" else contextlib.nullcontext():
        m.score(ref[: min(args.frames, 2)], test[: min(args.frames, 2)])  # warm-up
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        t0 = time.perf_counter()
        m.score(ref, test)
        sec = time.perf_counter() - t0
        faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0
    print(json.dumps({"seconds": sec, "faults": faults}))


def memory_ab(args: argparse.Namespace, rounds: int = 2) -> dict[str, dict[str, float]]:
    """:func:`memory_child` without and with, alternated in fresh processes; best of each."""
    out: dict[str, dict[str, float]] = {}
    for _ in range(rounds):
        for mode in ("off", "keep"):
            cmd = [sys.executable, __file__, "--_memory-child", mode, "--frames",
                   str(args.frames), "--size", str(args.size), "--threads",
                   str(torch.get_num_threads())]
            run = subprocess.run(cmd, capture_output=True, text=True, check=True)
            rec = json.loads(run.stdout.strip().splitlines()[-1])
            if mode not in out or rec["seconds"] < out[mode]["seconds"]:
                out[mode] = rec
    return out


def rss_run(seconds: float, height: int, width: int, variant: str, device: str,
            tmp: Path) -> dict[str, float]:
    from stimuli_manifests import write_video

    frames = max(1, round(30 * seconds))
    ref, test = tmp / f"ref{frames}.mkv", tmp / f"test{frames}.mkv"

    def frames_of(seed_noise: int | None):
        base = video(1, 1, height, width)
        for t in range(frames):
            f = np.roll(base, 3 * t, axis=2)
            yield f[0] if seed_noise is None else noisy(f, seed_noise + t)[0]

    write_video(ref, frames_of(None), 30)
    write_video(test, frames_of(100), 30)
    cmd = [sys.executable, __file__, "--_rss-child", str(ref), str(test), "--variants", variant,
           "--device", device, "--threads", str(torch.get_num_threads())]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    rec = json.loads(out.stdout.strip().splitlines()[-1])
    rec["frames"] = frames
    return rec


def default_precisions(device: str) -> list[str]:
    if device.startswith("cuda"):
        return ["fp32", "tf32", "bf16", "fp16"]
    return ["fp32", "bf16"] if cpu_bf16().supported else ["fp32"]


def usable_precisions(wanted: list[str], device: str) -> list[str]:
    """fp32 first; a precision the device refuses is reported and left out."""
    out = ["fp32"]
    bb = random_backbone(0)
    for p in wanted:
        if p == "fp32" or p in out:
            continue
        try:
            FeatureNet(bb, 3, device=device, precision=p)
        except CGVQMError as exc:
            print(f"  {p}: left out: {exc}")
            continue
        out.append(p)
    return out


def header(device: str) -> dict[str, object]:
    load = os.getloadavg()
    cuda = device.startswith("cuda")
    info = {"torch": torch.__version__, "threads": torch.get_num_threads(),
            "cpus": os.cpu_count(), "device": device,
            "device_name": torch.cuda.get_device_name() if cuda else cpu_name(),
            "cpu": cpu_name(), "cpu_bf16": cpu_bf16().isa or "none",
            "load_average": [round(x, 2) for x in load]}
    print(f"torch {info['torch']}, {info['threads']} threads, {info['cpus']} CPUs "
          f"({info['cpu']}, bf16 in hardware: {info['cpu_bf16']}), device {device} "
          f"({info['device_name']}), load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}")
    return info


def dq_of(a: CGVQMResult, b: CGVQMResult) -> dict[str, float]:
    return {"max_pool": abs(a.quality("max") - b.quality("max")),
            "mean_pool": abs(a.quality("mean") - b.quality("mean"))}


def per_pair_section(args, precs, bb, ref, tests, peak_best, fig) -> dict[str, dict]:
    T, S, dev = args.frames, args.size, args.device
    print(f"\nper pair of {T}x{S}x{S} (16 patches of {T}x{S // 4}x{S // 4}); |dq| against fp32 "
          "on this device:")
    base = {}
    for v in args.variants.split(","):
        w = weights_for(v)
        flop = 16 * conv_flops(FeatureNet(bb, w.n_levels), T, S // 4, S // 4, 2)
        spec = SPEC_TFLOP[v] * (T / 30) * (S / 512) ** 2
        print(f"  {v} ({flop / 1e12:.2f} TFLOP, spec budget scaled {spec:.2f}; weights "
              f"{w.kind}):")
        base[v] = {}
        for p in precs:
            m = CGVQM(v, weights=w, backbone=bb, device=dev, precision=p)
            m.score(ref[: min(T, 2)], tests[0][: min(T, 2)])  # warm-up
            res = None

            def run(m=m):
                nonlocal res
                res = m.score(ref, tests[0])

            sec = timed(run, args.repeats, dev)
            rate = flop / sec / 1e9
            # a shared host's speed drifts between sections: the peak measured right after
            # the pair gives a share that drift does not move
            near = conv_peak_of(T, S, dev, max(2, args.repeats), p)
            clock = StageClock(dev)  # the network's own share, for its rate alone
            m.score(ref, tests[0], clock=clock)
            bb_rate = flop / clock.seconds()["backbone"] / 1e9
            rec = {"s_per_pair": sec, "gflops": rate, "q_max": res.quality("max"),
                   "q_mean": res.quality("mean"), "backbone_gflops": bb_rate,
                   "share_of_peak": rate / peak_best[p], "peak_after_gflops": near,
                   "share_of_peak_after": rate / near,
                   "backbone_share_of_peak": bb_rate / peak_best[p]}
            tgt = ("; target 60 %: " + ("met" if bb_rate >= 0.6 * peak_best[p] else "MISSED")
                   if dev.startswith("cuda") and p in ("bf16", "fp16") else "")
            line = (f"    {p}: q {res.quality('max'):.3f} / {res.quality('mean'):.3f} (max / mean "
                    f"pooling), {sec:.2f} s/pair, {rate:.1f} GFLOP/s = "
                    f"{100 * rate / peak_best[p]:.0f}% of the {p} conv3d peak ("
                    f"{100 * rate / near:.0f}% of the peak measured right after the pair; the "
                    f"backbone alone: {100 * bb_rate / peak_best[p]:.0f}%{tgt})")
            if p != "fp32":
                d = dq_of(res, base[v]["fp32"]["result"])
                rec["dq_vs_fp32"] = d
                rec["speedup_vs_fp32"] = base[v]["fp32"]["s_per_pair"] / sec
                line += (f", x{rec['speedup_vs_fp32']:.2f} vs fp32, |dq| {d['max_pool']:.2e} "
                         f"(max pooling) {d['mean_pool']:.2e} (mean pooling)")
            print(line)
            base[v][p] = {**rec, "result": res}
    fig["per_pair"] = {v: {p: {k: x for k, x in r.items() if k != "result"}
                           for p, r in d.items()} for v, d in base.items()}
    return base


def ablation_section(args, precs, bb, ref, tests, fig) -> None:
    v, dev, reps = "cgvqm-2", args.device, args.repeats
    cuda = dev.startswith("cuda")
    w = weights_for(v)
    print(f"\nspeed-ups on {v} (s/pair; each measured back to back with the default, "
          "to limit drift from other load on the machine):")
    fast_m = CGVQM(v, weights=w, backbone=bb, device=dev)
    rows = {}
    layout = ("channels-last layout" if fast_m.net.channels_last
              else "default layout (against channels-last)")
    per_pass = fast_m.scorer.videos_per_pass(args.frames * (args.size // 4) ** 2)
    other = 2 if per_pass == 1 else 1
    for label, kw in ((layout, {"channels_last": not fast_m.net.channels_last}),
                      ("batch-norm folding", {"fuse_bn": False}),
                      (f"{per_pass} video(s) per pass, the default (against {other})",
                       {"batch_size": other})):
        m = CGVQM(v, weights=w, backbone=bb, device=dev, **kw)
        without = timed(lambda m=m: m.score(ref, tests[0]), reps, dev)
        fast = timed(lambda: fast_m.score(ref, tests[0]), reps, dev)
        rows[label] = without / fast
        print(f"  {label}: {without:.2f} without -> {fast:.2f} with = x{without / fast:.2f}")
    if not cuda and host_memory.available():
        mem = memory_ab(args)
        rows["freed memory kept"] = mem["off"]["seconds"] / mem["keep"]["seconds"]
        fig["host_memory"] = mem
        print(f"  freed host memory kept for the next pass (cgvqm_core.host_memory; fresh "
              f"processes, alternated): {mem['off']['seconds']:.2f} s and "
              f"{mem['off']['faults'] / 1e3:.0f} thousand page faults without -> "
              f"{mem['keep']['seconds']:.2f} s and {mem['keep']['faults'] / 1e3:.0f} thousand "
              f"with = x{rows['freed memory kept']:.2f}")
    sep = timed(lambda: [fast_m.score(ref, t) for t in tests], reps, dev) / 4
    reuse = timed(lambda: fast_m.score_many(ref, tests), reps, dev) / 4
    rows["reference reuse"] = sep / reuse
    print(f"  reference reuse (4 tests, one reference): {sep:.2f} -> {reuse:.2f} per pair "
          f"= x{sep / reuse:.2f}")
    if "bf16" in precs:  # what carrying tests as differences costs, and what it buys
        exact = CGVQM(v, weights=w, backbone=bb, device=dev, precision="fp32").score_many(
            ref, tests)
        diff_rows = {}
        for on in (False, True):
            m = CGVQM(v, weights=w, backbone=bb, device=dev, precision="bf16", differences=on)
            got = m.score_many(ref, tests)
            diff_rows[on] = {
                "single_s": timed(lambda m=m: m.score(ref, tests[0]), reps, dev),
                "reuse_s_per_pair": timed(lambda m=m: m.score_many(ref, tests), reps, dev) / 4,
                "dq_vs_fp32": max(max(dq_of(a, b).values()) for a, b in zip(got, exact,
                                                                            strict=True))}
        a, b = diff_rows[False], diff_rows[True]
        rows["bf16 differences (cost)"] = a["single_s"] / b["single_s"]
        fig["bf16_differences"] = {str(k): x for k, x in diff_rows.items()}
        print(f"  bf16, tests carried as differences from the reference: single pair "
              f"{a['single_s']:.2f} -> {b['single_s']:.2f} s, 4 tests per reference "
              f"{a['reuse_s_per_pair']:.2f} -> {b['reuse_s_per_pair']:.2f} s per pair; max "
              f"|dq| against fp32 over the 4 tests {a['dq_vs_fp32']:.2e} -> "
              f"{b['dq_vs_fp32']:.2e}")
    # The authors' run_cgvqm as its users run it: benchmarks/upstream_as_run.py follows its
    # data flow (host float32 videos, per-patch copies, batch 1, unfolded batch norm, default
    # layout, error map copied back per patch; PyTorch's defaults: TF32 on CUDA).
    up_m = UpstreamAsRun(bb, w, device=dev)
    up_m.score(ref[: min(args.frames, 2)], tests[0][: min(args.frames, 2)])  # warm-up
    up_res = up_m.score(ref, tests[0])
    up = min([up_res.seconds] + [up_m.score(ref, tests[0]).seconds
                                 for _ in range(max(args.repeats - 1, 0))])
    print(f"  upstream as its users run it (benchmarks/upstream_as_run.py"
          f"{', TF32 as PyTorch defaults' if cuda else ''}): {up:.2f} s/pair")
    targets = ({"auto": (1.5, 1e-3)} if cuda else {"fp32": (1.1, 1e-3), "bf16": (3.0, 0.05)})
    over = {}
    for p in ["auto", *precs] if cuda else precs:
        m = fast_m if p == "fp32" and not cuda else CGVQM(v, weights=w, backbone=bb,
                                                          device=dev, precision=p)
        res = m.score(ref, tests[0])
        one = timed(lambda m=m: m.score(ref, tests[0]), reps, dev)
        many = timed(lambda m=m: m.score_many(ref, tests), reps, dev) / 4
        d = dq_of(res, up_res)
        over[p] = {"single_s": one, "reuse_s_per_pair": many, "single_x": up / one,
                   "reuse_x": up / many, "dq_vs_upstream_as_run": d}
        tgt = targets.get(p)
        tgt_txt = ""
        if tgt:
            ok = up / one >= tgt[0] and max(d.values()) <= tgt[1]
            tgt_txt = (f" (target: single pair x{tgt[0]} at |dq| <= {tgt[1]:g}: "
                       f"{'met' if ok else 'MISSED'})")
        label = f"{p} (the default: {m.net.precision})" if p == "auto" else p
        print(f"  overall {label}: single pair {one:.2f} s = x{up / one:.2f}, per pair with 4 "
              f"tests sharing a reference {many:.2f} s = x{up / many:.2f}; |dq| against "
              f"upstream as run {max(d.values()):.2e}{tgt_txt}")
    if cuda:
        print("  tf32 configurations (single pair; |dq| against upstream as run):")
        tf = {}
        for fuse in (False, True):
            for bench_mode in (False, True):
                m = CGVQM(v, weights=w, backbone=bb, device=dev, precision="tf32",
                          fuse_bn=fuse, cudnn_benchmark=bench_mode)
                res = m.score(ref, tests[0])
                one = timed(lambda m=m: m.score(ref, tests[0]), reps, dev)
                d = dq_of(res, up_res)
                key = f"fuse_bn={fuse},cudnn_benchmark={bench_mode}"
                tf[key] = {"single_s": one, "single_x": up / one, "dq": d}
                print(f"    batch norm {'folded' if fuse else 'separate'}, cuDNN benchmark "
                      f"{'on' if bench_mode else 'off'}: {one:.3f} s = x{up / one:.2f}, |dq| "
                      f"{max(d.values()):.2e}")
        fig["tf32_configurations"] = tf
    if args.frames == 30 and args.size == 512 and not cuda:
        print("  (spec: upstream took 20.5 s per 30x512x512 CGVQM-2 pair on 2 idle cores "
              "of its machine; compare ratios, not seconds, across machines)")
    fig["ablation"] = {"gains": rows, "upstream_as_run_s": up, "overall": over}


def write_h264(path: Path, frames: np.ndarray, fps: int = 30) -> None:
    """H.264 at crf 18 in 4:2:0, how rendered stimuli are usually delivered."""
    import av

    with av.open(str(path), "w") as out:
        st = out.add_stream("libx264", rate=fps, options={"crf": "18", "preset": "fast"})
        st.width, st.height, st.pix_fmt = frames.shape[2], frames.shape[1], "yuv420p"
        for f in frames:
            out.mux(st.encode(av.VideoFrame.from_ndarray(f, format="rgb24")))
        out.mux(st.encode())


@contextlib.contextmanager
def h264_files(frames: int, size: int) -> Iterator[list[Path]]:
    """A reference and four noisy tests of it as H.264 files, in a temporary folder."""
    with tempfile.TemporaryDirectory() as tmp:
        ref = video(7, frames, size, size)
        paths = [Path(tmp) / "ref.mp4"] + [Path(tmp) / f"test{i}.mp4" for i in range(4)]
        write_h264(paths[0], ref)
        for i, pth in enumerate(paths[1:]):
            write_h264(pth, noisy(ref, 70 + i))
        yield paths


def breakdown_section(args, precs, bb, fig) -> None:
    """Where the time goes when scoring from files: decode, copy, backbone, pooling, idle
    (cgvqm_core.stage_clock), with decoding inline and in the prefetch thread."""
    dev = args.device
    cuda = dev.startswith("cuda")
    T, S = (90, 1024) if cuda else (args.frames, args.size)
    v = "cgvqm-2"
    w = weights_for(v)
    print(f"\ntime breakdown, {v}, {T}x{S}x{S} at 30 fps read from H.264 files (crf 18, "
          "4:2:0, as stimuli usually are); one pair, then 4 tests sharing a reference:")
    rows = {}
    with h264_files(T, S) as paths:
        for p in (["auto", *[x for x in precs if x in ("bf16", "fp16")]] if cuda else precs):
            for prefetch in (False, True):
                m = CGVQM(v, weights=w, backbone=bb, device=dev, precision=p, prefetch=prefetch)
                m.score(paths[0], paths[1])  # warm-up (and cuDNN's algorithm search)
                for label, tests in (("single", paths[1:2]), ("reuse4", paths[1:])):
                    clock = StageClock(dev)
                    m.score_many(paths[0], tests, clock=clock)
                    sec = clock.seconds()
                    per_pair = sec["wall"] / len(tests)
                    key = f"{p}/{'prefetch' if prefetch else 'inline'}/{label}"
                    rows[key] = {**sec, "pairs_per_min": 60 / per_pair}
                    print(f"  {p}, decoding {'ahead in a thread' if prefetch else 'inline'}, "
                          f"{'1 test' if label == 'single' else '4 tests'}: "
                          f"{60 / per_pair:.1f} pairs/min; {clock.report()}")
    fig["breakdown"] = rows


def trace_section(args, bb) -> None:
    """A torch.profiler trace of one scored pair (open it in Perfetto or chrome://tracing)."""
    from torch.profiler import ProfilerActivity, profile

    dev = args.device
    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if dev.startswith("cuda") else [])
    m = CGVQM("cgvqm-2", weights=weights_for("cgvqm-2"), backbone=bb, device=dev)
    ref = video(1, args.frames, args.size, args.size)
    m.score(ref, noisy(ref, 5))
    with profile(activities=acts) as prof:
        m.score(ref, noisy(ref, 6), clock=StageClock(dev))
    args.trace.mkdir(parents=True, exist_ok=True)
    out = args.trace / f"cgvqm_{dev.split(':')[0]}.json"
    prof.export_chrome_trace(str(out))
    sort = "self_device_time_total" if dev.startswith("cuda") else "self_cpu_time_total"
    print(f"\nprofiler: trace written to {out}; top operations:")
    print(prof.key_averages().table(sort_by=sort, row_limit=12))


def cuda_sections(args, precs, bb, ref, tests, base, fig) -> None:
    dev, reps = args.device, args.repeats
    print("\nCUDA fp32 against CPU fp32 on the same pair (TF32 off; target |dq| <= 1e-4):")
    parity = {}
    for v in args.variants.split(","):
        w = weights_for(v)
        cpu_res = CGVQM(v, weights=w, backbone=bb, device="cpu").score(ref, tests[0])
        d = dq_of(base[v]["fp32"]["result"], cpu_res)
        parity[v] = {**d, "q_cpu_max": cpu_res.quality("max"),
                     "q_cpu_mean": cpu_res.quality("mean"),
                     "max_abs_patch_error_diff": float(np.max(np.abs(
                         base[v]["fp32"]["result"].patch_errors - cpu_res.patch_errors)))}
        ok = "ok" if max(d.values()) <= 1e-4 else "MISSED"
        print(f"  {v}: |dq| {d['max_pool']:.2e} (max pooling), {d['mean_pool']:.2e} (mean "
              "pooling), largest patch-error difference "
              f"{parity[v]['max_abs_patch_error_diff']:.2e}: {ok}")
    fig["cuda_parity_vs_cpu"] = parity

    T3, S3 = 90, 1024
    print(f"\npairs per minute, 3 s {S3}x{S3} at 30 fps (48 patches of 30x{S3 // 4}x{S3 // 4}; "
          "peak GPU memory in brackets):")
    ref3 = video(3, T3, S3, S3)
    tests3 = [noisy(ref3, 30 + i) for i in range(4)]
    thr = {}
    for v in args.variants.split(","):
        w = weights_for(v)
        thr[v] = {}
        for p in precs:
            row = {}
            for label, bs in (("single", None), ("reuse4", None), ("reuse4_batch5", 5),
                              ("reuse4_batch10", 10), ("reuse4_batch20", 20),
                              ("reuse4_batch40", 40)):
                m = CGVQM(v, weights=w, backbone=bb, device=dev, precision=p, batch_size=bs)
                m.score(ref3[:30], tests3[0][:30])
                torch.cuda.reset_peak_memory_stats()
                if label == "single":
                    sec = timed(lambda m=m: m.score(ref3, tests3[0]), reps, dev)
                else:
                    sec = timed(lambda m=m: m.score_many(ref3, tests3), reps, dev) / 4
                row[label] = {"s_per_pair": sec, "pairs_per_min": 60 / sec,
                              "peak_gpu_gb": torch.cuda.max_memory_allocated() / 1024**3}
            thr[v][p] = row
            sweep = ", ".join(f"batch {k.removeprefix('reuse4_batch')} "
                              f"{r['pairs_per_min']:.1f} ({r['peak_gpu_gb']:.1f} GB)"
                              for k, r in row.items() if k.startswith("reuse4_batch"))
            tgt = ""
            if v == "cgvqm-2" and p in ("bf16", "fp16"):
                best = max(r["pairs_per_min"] for k, r in row.items() if k != "single")
                tgt = ("; target 350 with 4 tests per reference: "
                       f"{'met' if best >= 350 else 'MISSED'}")
            print(f"  {v} {p}: single {row['single']['pairs_per_min']:.1f} "
                  f"({row['single']['peak_gpu_gb']:.1f} GB), 4 tests per reference "
                  f"{row['reuse4']['pairs_per_min']:.1f} at the default batch "
                  f"({row['reuse4']['peak_gpu_gb']:.1f} GB); {sweep} pairs/min{tgt}")
    fig["cuda_throughput_3s_1024"] = thr

    print("\nCGVQM-2 vs CGVQM-5 on one 32x512x512 patch pair (reference + test; median of "
          f"{max(5, reps)} after warm-up):")
    g = torch.Generator().manual_seed(5)
    pr = torch.randint(0, 256, (32, 512, 512, 3), dtype=torch.uint8, generator=g)
    pt = (pr.int() + torch.randint(-8, 9, pr.shape, generator=g)).clamp(0, 255).to(torch.uint8)
    ratio = {}
    for p in precs:
        times = {}
        for v, n in (("cgvqm-2", 3), ("cgvqm-5", 6)):
            sc = PatchScorer(FeatureNet(bb, n, device=dev, precision=p), None)
            for _ in range(2):
                sc(pr, [pt])
            ts = []
            for _ in range(max(5, reps)):
                sync(dev)
                t0 = time.perf_counter()
                sc(pr, [pt])
                sync(dev)
                ts.append(time.perf_counter() - t0)
            times[v] = statistics.median(ts)
        r = times["cgvqm-5"] / times["cgvqm-2"]
        ratio[p] = {**times, "t5_over_t2": r, "less_time_pct": 100 * (1 - 1 / r)}
        print(f"  {p}: CGVQM-2 {1e3 * times['cgvqm-2']:.1f} ms, CGVQM-5 "
              f"{1e3 * times['cgvqm-5']:.1f} ms: CGVQM-2 is {100 * (r - 1):.0f} % faster "
              f"(takes {100 * (1 - 1 / r):.0f} % less time); paper: 27 % faster on an A100")
    fig["cuda_paper_ratio_32x512x512"] = ratio


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=512, help="frame size S of the pair (S x S)")
    ap.add_argument("--frames", type=int, default=30, help="frames T of the pair (fps 30)")
    ap.add_argument("--repeats", type=int, default=1, help="timed repeats (best is kept)")
    ap.add_argument("--variants", default="cgvqm-2,cgvqm-5")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--precisions",
                    help="comma-separated (default: fp32 and bf16 where the CPU has it; on "
                         "CUDA fp32,tf32,bf16,fp16)")
    ap.add_argument("--threads", type=int, help="torch threads (default: torch's choice)")
    ap.add_argument("--no-ablation", action="store_true", help="skip the optimisation speed-ups")
    ap.add_argument("--no-breakdown", action="store_true",
                    help="skip the time breakdown (decode, copy, backbone, pooling, idle)")
    ap.add_argument("--breakdown-only", action="store_true",
                    help="only the time breakdown (and --trace)")
    ap.add_argument("--trace", type=Path,
                    help="also write a torch.profiler trace of one pair into this folder")
    ap.add_argument("--rss-only", action="store_true", help="only the peak-RSS measurement")
    ap.add_argument("--rss-seconds",
                    help="lengths (s) of the 1080p30 pairs for peak RSS; 0 skips (default 1,10 "
                         "on CPU, 0 on CUDA)")
    ap.add_argument("--rss-height", type=int, default=1080)
    ap.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    ap.add_argument("--_rss-child", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--_memory-child", choices=("off", "keep"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    variants = args.variants.split(",")
    cuda = args.device.startswith("cuda")
    if args.rss_seconds is None:
        args.rss_seconds = "0" if cuda else "1,10"
    if args.threads:
        torch.set_num_threads(args.threads)
    if args._rss_child:
        rss_child(*args._rss_child, variants[0], args.device)
        return
    if args._memory_child:
        memory_child(args, args._memory_child)
        return

    fig: dict[str, object] = {"machine": header(args.device)}
    if not cuda:
        print("CUDA: not measured in this run; --device cuda runs the same code path")
    T, S = args.frames, args.size
    if args.rss_only:
        fig["rss"] = rss_section(args, variants)
        return
    wanted = args.precisions.split(",") if args.precisions else default_precisions(args.device)
    precs = usable_precisions(wanted, args.device)
    print(f"precisions: {', '.join(precs)} (fp32 is upstream-identical; the others are not "
          "bit-exact)")
    if args.breakdown_only:
        bb = random_backbone(0)
        breakdown_section(args, precs, bb, fig)
        if args.trace:
            trace_section(args, bb)
        return
    peak_best, peaks = {}, {}
    for p in precs:
        peaks[p] = conv_peaks(T, S, args.device, max(2, args.repeats), p)
        peak_best[p] = max(peaks[p].values())
        print(f"conv3d peak {p} (64->64 3x3x3 on 2x64x{T}x{S // 8}x{S // 8}): "
              + ", ".join(f"{k} {x:.1f}" for k, x in peaks[p].items()) + " GFLOP/s")
    fig["conv_peak_gflops"] = peaks

    ref = video(1, T, S, S)
    tests = [noisy(ref, 10 + i) for i in range(4)]
    bb = random_backbone(0)
    fig["backbone_sha256"] = bb.sha256
    base = per_pair_section(args, precs, bb, ref, tests, peak_best, fig)
    if not args.no_ablation:
        ablation_section(args, precs, bb, ref, tests, fig)
    if cuda:
        cuda_sections(args, precs, bb, ref, tests, base, fig)
    if not args.no_breakdown:
        breakdown_section(args, precs, bb, fig)
    if args.trace:
        trace_section(args, bb)
    fig["rss"] = rss_section(args, variants)
    if args.json:
        args.json.write_text(json.dumps(fig, indent=1, default=str))
        print(f"\nfigures written to {args.json}")


def rss_section(args: argparse.Namespace, variants: list[str]) -> list[dict]:
    lengths = [float(x) for x in str(args.rss_seconds).split(",") if float(x) > 0]
    out = []
    if lengths:
        h = args.rss_height
        w = h * 16 // 9
        print(f"\npeak RSS, {w}x{h} at 30 fps, {variants[0]}, streamed from lossless files:")
        with tempfile.TemporaryDirectory() as tmp:
            for s in lengths:
                rec = rss_run(s, h, w, variants[0], args.device, Path(tmp))
                out.append(rec)
                print(f"  {s:g} s ({rec['frames']} frames, {rec['patches']} patches): peak RSS "
                      f"{rec['peak_rss_gb']:.2f} GB, {rec['seconds']:.1f} s")
    return out


if __name__ == "__main__":
    main()
