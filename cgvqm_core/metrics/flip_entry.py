"""FLIP (Andersson et al. 2020), NVIDIA's LDR image difference evaluator, per frame.

Through the ``flip-evaluator`` package (BSD-3-Clause; numpy only). Frames are sRGB in
[0, 1]; the mean FLIP error of every frame is averaged over frames (lower is better).
Pixels per degree come from the study's viewing condition (:mod:`.viewing`).
``flip-evaluator`` exits the process on bad arguments: they are checked here first and a
``SystemExit`` from it is turned into an error.
"""

from __future__ import annotations

import contextlib
import io
import math
from typing import Any

import numpy as np

from ..errors import CGVQMError
from .registry import (
    IMAGE,
    LOWER,
    PERCEPTUAL_IMAGE,
    Availability,
    Entry,
    FrameScorer,
    MetricOptions,
    MetricSpec,
    module_available,
    package_version,
)

SPEC = MetricSpec(
    name="flip", title="FLIP (LDR)", family="flip_entry", direction=LOWER, value_range=(0, 1),
    kind=IMAGE, colour="sRGB frames, FLIP's own YCxCz/L*a*b* pipeline",
    licence="flip-evaluator: BSD-3-Clause (NVIDIA)", reference="Andersson et al. 2020",
    devices=("cpu",), min_size=1, reads=("viewing",))


def flip_frame(ref: np.ndarray, test: np.ndarray, ppd: float) -> float:
    """Mean LDR-FLIP error of one (H, W, 3) float32 frame pair in [0, 1]."""
    import flip_evaluator

    if not (ppd > 0 and math.isfinite(ppd)):
        raise CGVQMError(f"FLIP needs a positive pixels-per-degree, got {ppd}")
    try:
        with contextlib.redirect_stdout(io.StringIO()) as out:
            _, mean, _ = flip_evaluator.evaluate(
                np.ascontiguousarray(ref, dtype=np.float32),
                np.ascontiguousarray(test, dtype=np.float32), "LDR", inputsRGB=True,
                applyMagma=False, computeMeanError=True, parameters={"ppd": float(ppd)})
    except SystemExit:
        raise CGVQMError(f"flip-evaluator refused its arguments: {out.getvalue().strip()}"
                         ) from None
    return float(mean)


class FlipScorer(FrameScorer):
    spec = SPEC

    def __init__(self, options: MetricOptions) -> None:
        self.ppd = options.viewing.pixels_per_degree

    def settings(self) -> dict[str, Any]:
        return {"frames": "mean", "ppd": round(self.ppd, 4), "range": "LDR"}

    def provenance(self) -> dict[str, Any]:
        return {"flip-evaluator": package_version("flip-evaluator")}

    def score_frames(self, test: Any, ref: Any) -> np.ndarray:
        t = test.permute(0, 2, 3, 1).cpu().numpy()
        r = ref.permute(0, 2, 3, 1).cpu().numpy()
        return np.array([flip_frame(r[i], t[i], self.ppd) for i in range(len(t))])


class FlipEntry(Entry):
    spec = SPEC

    def availability(self) -> Availability:
        return module_available("flip_evaluator")

    def build(self, options: MetricOptions) -> FlipScorer:
        return FlipScorer(options)


ENTRIES: tuple[Entry, ...] = (FlipEntry(),)
LISTING_GROUP = PERCEPTUAL_IMAGE
