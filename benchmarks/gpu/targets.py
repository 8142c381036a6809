"""Issue #21's targets, and the verdicts session.py prints on them from its figures.

Kept apart from the measuring: a section fills ``Session.fig``; these read it (and only it,
with the device and the precisions offered), so the tests can judge made-up figures.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import stem_kernels as stem_kernels_mod

if TYPE_CHECKING:
    from session import Session

TARGETS = {  # the issue's, on CUDA
    "auto_single_x": 1.5, "auto_set_x": 2.5, "dq_upstream": 1e-3, "low_share": 0.60,
    "pairs_min": 350.0, "dq_low": 0.05, "parity": 1e-4,
}


def many_gpus(ss: Session) -> list[str]:
    """The many-GPU model: GPUs scale independently (one Ray task per GPU, nothing shared
    but the host), until the host cannot decode fast enough. The host's ceiling is the
    ``decoding`` section's measured rate (a reference and its tests decoded at once, on all
    cores); without it, one core per video at the breakdown's single-video time."""
    rates = [r for k, r in (ss.fig.get("throughput") or {}).items() if "reuse4" in k]
    rates += list(fast_within_bound(ss.fig).values())
    files = [r["pairs_per_min"] for sec in ("breakdown", "fast_breakdown")
             for r in (ss.fig.get(sec) or {}).values()
             if isinstance(r, dict) and "pairs_per_min" in r]
    if not rates or not files:
        return ["many GPUs: not modelled (no in-memory rate or no rate reading files)"]
    in_memory = max(r["pairs_per_min"] for r in rates)
    best = min(in_memory, max(files))  # one GPU reading H.264 files, as a study is scored
    dec = ss.fig.get("decoding")
    cores = os.cpu_count() or 1
    if dec:
        host = max(dec["threads_pairs_per_min"], dec["processes_pairs_per_min"])
        how = (f"decoding, measured at {host:.0f} pairs/min on this host's {cores} cores "
               "(a reference and 4 tests at once)")
    else:
        bd = ss.fig.get("breakdown") or ss.fig.get("fast_breakdown") or {}
        decode_pair = 1.25 * bd.get("decode_one_video_s", float("nan"))
        host = 60 * cores / decode_pair
        how = f"decoding, {decode_pair:.2f} s of one core per pair on {cores} cores"
    n = host / best
    return [f"many GPUs (model from this GPU; one task per GPU): N x {best:.0f} pairs/min "
            f"(best 3 s {ss.sizes.size3}x{ss.sizes.size3} rate here from H.264 files; "
            f"{in_memory:.0f} from memory) until {how} saturates the host: N <= {n:.1f} "
            f"GPUs per such host; beyond that, more hosts (Ray, one task per GPU) or "
            f"stimuli decoded ahead"]


def drift_worst(rec: dict) -> dict[str, tuple[float, str]]:
    """The worst |dq| against fp32 of each precision over bench_precision's sets and
    poolings, with where it occurred."""
    out: dict[str, tuple[float, str]] = {}
    for r in (rec.get("figures") or {}).get("results", []):
        for p, fig in r.get("other", {}).items():
            if "max_pool" not in fig:  # a precision bench_precision refused
                continue
            for pool in ("max_pool", "mean_pool"):
                dq = fig[pool]["max"]
                if dq > out.get(p, (-1.0, ""))[0]:
                    out[p] = (dq, f"{r['variant']}, {pool.replace('_', ' ')}ing")
    return out


def fast_within_bound(f: dict) -> dict[str, dict]:
    """The fast paths measured whose |dq| against fp32 stayed within the bound, on the 512
    pair and (where fast_drift and real_drift measured them) on the demo and real sets."""
    worst = [drift_worst(f.get(sec) or {}) for sec in ("fast_drift", "real_drift")]
    return {k: r for k, r in (f.get("fastpath") or {}).items() if "pairs_per_min" in r
            and r["max_dq_vs_fp32"] <= TARGETS["dq_low"]
            and all(w.get(k, (0.0, ""))[0] <= TARGETS["dq_low"] for w in worst)}


def summary(ss: Session) -> list[str]:
    """One line per target of the issue, with what was measured."""
    f, t, lines = ss.fig, TARGETS, []

    def row(label: str, value: str, ok: bool | str | None) -> None:
        verdict = ok if isinstance(ok, str) else (
            "not measured" if ok is None else ("met" if ok else "MISSED"))
        lines.append(f"  {label:<58} {value:<28} {verdict}")

    d = f.get("defaults", {}).get("auto")
    row(f"default on {ss.device}: single pair >= x{t['auto_single_x']} upstream as run",
        f"x{d['single_x']:.2f}, |dq| {d['dq_vs_upstream']:.1e}" if d else "-",
        None if not d else d["single_x"] >= t["auto_single_x"]
        and d["dq_vs_upstream"] <= t["dq_upstream"])
    ps = f.get("paper_set")
    row(f"default: paper-shaped set >= x{t['auto_set_x']} upstream as run",
        f"x{ps['x']:.2f}, |dq| {ps['max_dq']:.1e}" if ps else "-",
        None if not ps else ps["x"] >= t["auto_set_x"] and ps["max_dq"] <= t["dq_upstream"])
    sh = f.get("shares", {})
    for p in ss.low():
        r = sh.get(p)
        row(f"{p}: backbone >= {100 * t['low_share']:.0f} % of the conv3d peak",
            f"{100 * r['backbone_share']:.0f} % (whole run {100 * r['wall_share']:.0f} %)"
            if r else "-", None if not r else r["backbone_share"] >= t["low_share"])
    thr = f.get("throughput", {})
    low = [r["pairs_per_min"] for k, r in thr.items() if k.split("/")[0] in ss.low()]
    row(f"bf16/fp16: >= {t['pairs_min']:.0f} pairs/min, CGVQM-2 3 s 1024^2, 4 per ref",
        f"{max(low):.0f} pairs/min" if low else "-",
        None if not low else max(low) >= t["pairs_min"])
    par = f.get("parity")
    row(f"fp32 {ss.device} against CPU: |dq| <= {t['parity']:g}",
        ", ".join(f"{max(r['max_pool'], r['mean_pool']):.1e}" for r in par.values())
        if par else "-", None if not par else all(r["ok"] for r in par.values()))
    worst = drift_worst(f.get("drift") or {})
    for p in ss.low():
        w = worst.get(p)
        row(f"{p}: |dq| against fp32 on the demo <= {t['dq_low']} (worst case)",
            f"{w[0]:.3f} ({w[1]})" if w else "-", None if not w else w[0] <= t["dq_low"])
    fast_worst = drift_worst(f.get("fast_drift") or {})
    ok = fast_within_bound(f)
    if f.get("fastpath") or f.get("sections", {}).get("fastpath"):
        best = max(ok, key=lambda k: ok[k]["pairs_per_min"]) if ok else None
        row(f"fast paths: >= {t['pairs_min']:.0f} pairs/min (best within the drift bound)",
            f"{ok[best]['pairs_per_min']:.0f} ({best})" if best else "-",
            None if not best else ok[best]["pairs_per_min"] >= t["pairs_min"])
        share = max(ok, key=lambda k: ok[k]["backbone_share"]) if ok else None
        row(f"fast paths: backbone >= {100 * t['low_share']:.0f} % of the conv3d peak",
            f"{100 * ok[share]['backbone_share']:.0f} % ({share})" if share else "-",
            None if not share else ok[share]["backbone_share"] >= t["low_share"])
        for k, (dq, where) in fast_worst.items():
            row(f"{k}: |dq| on the demo <= {t['dq_low']}", f"{dq:.3f} ({where})",
                dq <= t["dq_low"])
    for k, (dq, where) in drift_worst(f.get("real_drift") or {}).items():
        row(f"{k}: |dq| on real content <= {t['dq_low']}", f"{dq:.3f} ({where})",
            dq <= t["dq_low"])
    sk = f.get("stem_kernels")
    best = stem_kernels_mod.fastest_exact(sk) if sk else None
    limit = stem_kernels_mod.TARGET_S_PER_PAIR
    row(f"stem alone with fp32's numbers: <= {limit} s/pair (fastest way)",
        f"{sk[best]['s_per_pair']:.4f} s ({best})" if best else "-",
        None if not best else sk[best]["s_per_pair"] <= limit)
    up = f.get("upstream_own", {}).get("cgvqm-2")
    row("against the authors' own run_cgvqm (files, per call)",
        f"x{up['auto']['x']:.2f}, |dq| {up['auto']['dq']:.1e}" if up else "-",
        "(no target)" if up else None)
    return lines
