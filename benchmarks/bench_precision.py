"""Score drift of bf16 / fp16 / tf32 against fp32, and CPU-GPU fp32 parity (prints figures).

For every test video of the chosen sets, q is computed with fp32 and with each other
precision on the same device, under max and mean pooling; printed per set, variant,
pooling and precision: max and mean |dq| (0..100 scale) and |dq| relative to the pooled
error 100 - q (a random backbone can put q far below 0, where |dq| grows with the error; the
relative figure carries over to other q ranges), with seconds per pair. With
``--device cuda --parity-cpu`` the fp32 GPU scores are also compared with fp32 on the CPU
(target |dq| <= 1e-4; fp32 on CUDA runs with TF32 off).

The backbone is a seeded random R3D-18 (``--random-backbone``, default seed 0, the same on
every machine: its sha256 is printed) and the feature weights are the published omega/alpha
(``--weights-dir``, default ../shared/data/cgvqm_upstream or the weights cache). A random
backbone is a PROXY for the Kinetics-400 one: its activations, and so the drift, differ.

Sets:
  --manifest M      a study manifest (e.g. the demo study of ``cgvq-study synth``): every
                    condition against its reference
  --real FILE       a real video (repeatable): the first --real-frames frames, scaled to
                    --real-width, against four distortions made here: H.264 at CRF 32 and
                    42 (PyAV/libx264), a Gaussian blur (sigma 1.5 px) and noise (sigma 6)
  --real-pair R,T   a real reference/test pair used as it is

    python benchmarks/bench_precision.py --manifest demo/manifest.json --real clip.mp4
    python benchmarks/bench_precision.py --device cuda --precisions fp32,tf32,bf16,fp16 \\
        --parity-cpu --manifest demo/manifest.json --json drift_cuda.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from cgvqm_core import CGVQM
from cgvqm_core.hub import random_backbone
from cgvqm_core.precision import cpu_bf16, cpu_name

HERE = Path(__file__).resolve().parent
SHARED_WEIGHTS = HERE.parent.parent / "shared" / "data" / "cgvqm_upstream"


@dataclass
class PairSet:
    """Pairs grouped by reference: (reference, [tests], [test names], fps of arrays)."""

    name: str
    groups: list[tuple[object, list[object], list[str], float | None]] = field(
        default_factory=list)

    @property
    def n_pairs(self) -> int:
        return sum(len(g[1]) for g in self.groups)


def manifest_set(path: Path) -> PairSet:
    from stimuli_manifests import load_manifest

    loaded = load_manifest(path)
    out = PairSet(f"manifest {path.parent.name}")
    by_ref: dict[str, list] = {}
    for s in loaded.manifest.stimuli(include_hidden_references=False):
        by_ref.setdefault(s.reference, []).append(s)
    for ref_id, stims in by_ref.items():
        out.groups.append((loaded.reference_path(ref_id),
                           [loaded.stimulus_path(s.id) for s in stims], [s.id for s in stims],
                           None))
    return out


def _scaled(path: Path, frames: int, width: int) -> tuple[np.ndarray, float]:
    import torch.nn.functional as F

    from stimuli_manifests import open_video

    src = open_video(path)
    arr = src.read(max_frames=frames)
    h, w = arr.shape[1:3]
    if width and w > width:
        nh = int(round(h * width / w / 2) * 2)
        t = torch.from_numpy(arr).permute(0, 3, 1, 2).float()
        t = F.interpolate(t, size=(nh, width), mode="area")
        arr = t.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).contiguous().numpy()
    return arr, float(src.info.fps)


def _h264(frames: np.ndarray, fps: float, crf: int) -> np.ndarray:
    """Encode with libx264 (yuv420p) at ``crf`` in memory and decode again."""
    import io
    from fractions import Fraction

    import av

    buf = io.BytesIO()
    with av.open(buf, mode="w", format="matroska") as c:
        st = c.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        st.width, st.height, st.pix_fmt = frames.shape[2], frames.shape[1], "yuv420p"
        st.options = {"crf": str(crf), "preset": "medium"}
        for f in frames:
            for pkt in st.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                c.mux(pkt)
        for pkt in st.encode():
            c.mux(pkt)
    buf.seek(0)
    with av.open(buf) as c:
        out = [fr.to_ndarray(format="rgb24") for fr in c.decode(video=0)]
    return np.stack(out)


def real_set(paths: list[Path], frames: int, width: int, seed: int) -> PairSet:
    from scipy.ndimage import gaussian_filter

    out = PairSet("real content")
    rng = np.random.default_rng(seed)
    for p in paths:
        ref, fps = _scaled(p, frames, width)
        tests = [_h264(ref, fps, 32), _h264(ref, fps, 42),
                 gaussian_filter(ref, sigma=(0, 1.5, 1.5, 0)),
                 np.clip(ref + rng.normal(0, 6, ref.shape), 0, 255).astype(np.uint8)]
        names = [f"{p.stem}_crf32", f"{p.stem}_crf42", f"{p.stem}_blur", f"{p.stem}_noise"]
        out.groups.append((ref, tests, names, fps))
    return out


def pair_set(pairs: list[str]) -> PairSet:
    out = PairSet("real pairs")
    for spec in pairs:
        r, t = spec.split(",")
        out.groups.append((Path(r), [Path(t)], [Path(t).stem], None))
    return out


def score_set(metric: CGVQM, ps: PairSet) -> tuple[np.ndarray, float]:
    """(n_pairs, 2) q under max and mean pooling, and seconds per pair (reference reuse)."""
    rows = []
    t0 = time.perf_counter()
    for ref, tests, _, fps in ps.groups:
        for res in metric.score_many(ref, tests, fps=fps, allow_resample=True):
            rows.append((res.quality("max"), res.quality("mean")))
    if metric.net.device.type == "cuda":
        torch.cuda.synchronize()
    return np.array(rows), (time.perf_counter() - t0) / max(ps.n_pairs, 1)


def weights_path(variant: str, wdir: str | None) -> str:
    for d in [wdir, os.environ.get("CGVQM_WEIGHTS_DIR"), SHARED_WEIGHTS]:
        if d and (Path(d) / f"{variant}.pickle").is_file():
            return str(Path(d) / f"{variant}.pickle")
    return variant  # the published weights through the cache (may download)


PLAIN = "-plain"
#: ``+option`` suffixes of a precision label and the CGVQM arguments they stand for
OPTIONS = {"tf32stem": {"tf32_stem": True}, "lowstem": {"fp32_stem": False},
           "fused": {"fused": True}, "padstem": {"pad_stem": True},
           "exactstem": {"tf32_stem": False}, "nofused": {"fused": False},
           "nopad": {"pad_stem": False}, "splitstem": {"split_stem": "int"},
           "split3stem": {"split_stem": "3xtf32"}, "stem2d": {"stem_2d": True},
           "s2d": {"stem_2d": True, "stem_s2d": True}}


def parse_config(label: str) -> tuple[str, dict]:
    """``fp16+fused+padstem`` -> ("fp16", {"fused": True, "pad_stem": True}); ``bf16-plain``
    is bf16 without carrying the tests as differences (so is bf16 with fused or padstem)."""
    prec, *opts = label.split("+")
    kw: dict = {}
    if prec.endswith(PLAIN):
        prec, kw["differences"] = prec[: -len(PLAIN)], False
    for o in opts:
        if o not in OPTIONS:
            raise ValueError(f"unknown option +{o} in {label!r}; known: {', '.join(OPTIONS)}")
        kw.update(OPTIONS[o])
    if prec == "bf16" and any(kw.get(k) for k in ("fused", "pad_stem", "split_stem",
                                                    "stem_2d", "stem_s2d")):
        kw["differences"] = False
    return prec, kw


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.2e}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--precisions", help="comma-separated; fp32 is always the reference "
                                         "(default: bf16 on CPU, tf32,bf16,fp16 on CUDA); "
                                         "bf16-plain is bf16 without carrying the tests as "
                                         "differences from their reference; +tf32stem, "
                                         "+lowstem, +fused, +padstem, +splitstem "
                                         "(int), +split3stem (3xtf32), +stem2d, +s2d (the 2D stem "
                                         "over its stride phases) (or +exactstem, "
                                         "+nofused, +nopad) set GPU options, e.g. "
                                         "fp16+exactstem")
    ap.add_argument("--variants", default="cgvqm-2,cgvqm-5")
    ap.add_argument("--manifest", action="append", default=[], type=Path)
    ap.add_argument("--real", action="append", default=[], type=Path)
    ap.add_argument("--real-pair", action="append", default=[])
    ap.add_argument("--real-frames", type=int, default=50)
    ap.add_argument("--real-width", type=int, default=640)
    ap.add_argument("--random-backbone", type=int, default=0, metavar="SEED")
    ap.add_argument("--weights-dir", help="folder with cgvqm-2.pickle / cgvqm-5.pickle")
    ap.add_argument("--parity-cpu", action="store_true",
                    help="also score fp32 on the CPU and compare with the device's fp32")
    ap.add_argument("--threads", type=int)
    ap.add_argument("--json", type=Path, help="write every figure and score here")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    cuda = args.device.startswith("cuda")
    precs = (args.precisions or ("tf32,bf16,fp16" if cuda else "bf16")).split(",")
    precs = [p for p in precs if p != "fp32"]
    sets = [manifest_set(m) for m in args.manifest]
    if args.real:
        sets.append(real_set(args.real, args.real_frames, args.real_width, 0))
    if args.real_pair:
        sets.append(pair_set(args.real_pair))
    if not sets:
        ap.error("give at least one --manifest, --real or --real-pair")
    bb = random_backbone(args.random_backbone)
    load = os.getloadavg()
    head = {"torch": torch.__version__, "device": args.device,
            "device_name": torch.cuda.get_device_name() if cuda else cpu_name(),
            "threads": torch.get_num_threads(), "load_average": load,
            "cpu_bf16": cpu_bf16().isa or "none",
            "backbone": bb.label, "backbone_sha256": bb.sha256}
    print(json.dumps(head))
    print("random backbone: the drift is a PROXY for the Kinetics-400 backbone's")
    record: dict = {"head": head, "results": []}
    for v in args.variants.split(","):
        wp = weights_path(v, args.weights_dir)
        for ps in sets:
            ref_m = CGVQM(v, weights=wp, backbone=bb, device=args.device, precision="fp32")
            q32, s32 = score_set(ref_m, ps)
            row = {"variant": v, "set": ps.name, "pairs": ps.n_pairs, "fp32_s_per_pair": s32,
                   "q_fp32": q32.tolist(), "other": {}}
            print(f"\n{v}, {ps.name}: {ps.n_pairs} pairs, fp32 {s32:.2f} s/pair, q "
                  f"{q32[:, 0].min():.2f}..{q32[:, 0].max():.2f} (max pooling), "
                  f"{q32[:, 1].min():.2f}..{q32[:, 1].max():.2f} (mean pooling)")
            comps = []
            if cuda and args.parity_cpu:
                comps.append(("fp32 cpu", "cpu", "fp32"))
            comps += [(p, args.device, p) for p in precs]
            for label, dev, p in comps:
                try:
                    p, kw = parse_config(p)
                    m = CGVQM(v, weights=wp, backbone=bb, device=dev, precision=p, **kw)
                except Exception as exc:  # refused precision: say so and go on
                    print(f"  {label}: {exc}")
                    row["other"][label] = {"refused": str(exc)}
                    continue
                q, s = score_set(m, ps)
                dq = np.abs(q - q32)
                rel = dq / np.maximum(np.abs(100 - q32), 1e-6)  # relative to the pooled error
                rec = {"s_per_pair": s, "speedup": s32 / s, "q": q.tolist()}
                for k, col in (("max_pool", 0), ("mean_pool", 1)):
                    inside = (q32[:, col] >= 0) & (q32[:, col] <= 100)
                    rec[k] = {"max": float(dq[:, col].max()), "mean": float(dq[:, col].mean()),
                              "rel_max": float(rel[:, col].max()),
                              "rel_mean": float(rel[:, col].mean()),
                              "max_0_100": float(dq[inside, col].max()) if inside.any()
                              else None}
                row["other"][label] = rec
                a, b = rec["max_pool"], rec["mean_pool"]
                print(f"  {label:10s} |dq| max pooling: max {a['max']:.2e} mean {a['mean']:.2e} "
                      f"(relative to 100-q: max {a['rel_max']:.1e}; pairs with 0 <= q <= 100: "
                      f"max {_fmt(a['max_0_100'])}); mean pooling: max {b['max']:.2e} mean "
                      f"{b['mean']:.2e} (relative max {b['rel_max']:.1e}; 0 <= q <= 100: max "
                      f"{_fmt(b['max_0_100'])}); {s:.2f} s/pair (x{s32 / s:.2f} vs fp32)")
            record["results"].append(row)
    if args.json:
        args.json.write_text(json.dumps(record, indent=1))
        print(f"\nwritten: {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
