"""How long synthetic stimuli take: rendering per frame and each distortion family.

Prints one line per stage for one scene at the given size (defaults: the demo's 128x128,
1 s). Usage: python benchmarks/bench_synth.py [--size 128] [--seconds 1] [--scene lattice]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from study_app.synth import METHODS, SynthOptions, synthesize
from study_app.synth.renderer import SceneRenderer, create_context


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--seconds", type=float, default=1.0)
    p.add_argument("--scene", default="lattice")
    a = p.parse_args()

    ctx = create_context()
    r = SceneRenderer(ctx, a.scene, a.size, a.size, seed=0)
    r.reference(0.0, 0, mc=True)  # warm-up (shader compilation)
    for label, kwargs in (("reference (16 spp, expected lighting)", {"mc": False}),
                          ("reference + Monte Carlo 2..256 spp", {"mc": True})):
        t0 = time.perf_counter()
        for i in range(5):
            r.reference(i / 60, i, **kwargs)
        print(f"{label:<40s} {1000 * (time.perf_counter() - t0) / 5:8.1f} ms/frame")
    t0 = time.perf_counter()
    for i in range(5):
        r.gbuffer(i / 60, (i - 2) / 60, i)
    print(f"{'G-buffer (1 spp)':<40s} {1000 * (time.perf_counter() - t0) / 5:8.1f} ms/frame")
    r.release()
    ctx.release()

    with tempfile.TemporaryDirectory() as tmp:
        for method in METHODS:
            t0 = time.perf_counter()
            synthesize(Path(tmp) / method, SynthOptions(width=a.size, height=a.size,
                                                        seconds=a.seconds, scenes=(a.scene,),
                                                        methods=(method,)), progress=False)
            print(f"{'synth, render + ' + method + ' (4 levels)':<40s} "
                  f"{time.perf_counter() - t0:8.1f} s")
        t0 = time.perf_counter()
        synthesize(Path(tmp) / "all", SynthOptions(width=a.size, height=a.size,
                                                   seconds=a.seconds), progress=False)
        print(f"{'synth, demo default (2 scenes, all)':<40s} {time.perf_counter() - t0:8.1f} s")


if __name__ == "__main__":
    main()
