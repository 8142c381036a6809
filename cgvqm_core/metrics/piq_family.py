"""The classical image metrics of the CGVQM paper's comparison, as registry entries.

As in the paper (which used PIQ), each is computed per frame on RGB in [0, 1] and averaged
over frames. The functions are this package's own (:mod:`.iqa`), checked against PIQ 0.8.
Frames are decoded by FFmpeg (PyAV) to 8-bit RGB: YUV sources use the matrix and range their
stream declares (BT.601 limited range when unspecified, FFmpeg's default); the lossless RGB
stimuli the toolkit writes are read back exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .registry import (
    CLASSICAL_IMAGE,
    HIGHER,
    IMAGE,
    LOWER,
    Entry,
    FrameScorer,
    MetricOptions,
    MetricSpec,
)

PIQ_LICENCE = "definitions as PIQ 0.8 (Apache-2.0); own implementation"
MS_MIN = 161


@dataclass(frozen=True)
class _Def:
    name: str
    title: str
    direction: str
    value_range: tuple[float | None, float | None]
    colour: str
    reference: str
    function: str  # attribute of .iqa
    min_size: int = 1


DEFS = (
    _Def("psnr", "PSNR", HIGHER, (0, 80), "RGB, one MSE over the three channels (80 dB cap "
         "from the 1e-8 floor)", "PSNR", "psnr"),
    _Def("ssim", "SSIM", HIGHER, (-1, 1), "RGB, per channel then averaged; frames average-"
         "pooled by round(min(H,W)/256)", "Wang et al. 2004", "ssim", 11),
    _Def("ms-ssim", "MS-SSIM", HIGHER, (0, 1), "RGB, per channel then averaged",
         "Wang et al. 2003", "ms_ssim", MS_MIN),
    _Def("iw-ssim", "IW-SSIM", HIGHER, (0, 1), "luma (Y of YIQ, BT.601 weights)",
         "Wang & Li 2011", "iw_ssim", MS_MIN),
    _Def("vif", "VIFp", HIGHER, (0, None), "luma (BT.601 weights)", "Sheikh & Bovik 2006",
         "vif_p", 41),
    _Def("fsim", "FSIMc", HIGHER, (0, 1), "YIQ: phase congruency and gradient on Y, "
         "chroma similarity on I and Q", "Zhang et al. 2011", "fsim", 8),
    _Def("sr-sim", "SR-SIM", HIGHER, (0, 1), "luma (Y of YIQ)", "Zhang & Li 2012", "srsim",
         40),
    _Def("gmsd", "GMSD", LOWER, (0, None), "luma (Y of YIQ)", "Xue et al. 2014", "gmsd", 4),
    _Def("ms-gmsd", "MS-GMSD", LOWER, (0, None), "luma (Y of YIQ); chroma term off (PIQ "
         "default)", "Zhang et al. 2017", "ms_gmsd", 17),
    _Def("vsi", "VSI", HIGHER, (0, 1), "RGB: SDSP saliency in CIELAB, gradient and chroma in "
         "LMN", "Zhang et al. 2014", "vsi", 8),
    # DSS pools the worst 5 % of its 8x8 DCT blocks: fewer than 11 blocks give none (NaN)
    _Def("dss", "DSS", HIGHER, (0, 1), "luma (Y of YIQ)", "Balanis et al. 2015", "dss", 32),
    _Def("haarpsi", "HaarPSI", HIGHER, (0, 1), "YIQ: Haar wavelets on Y, I and Q",
         "Reisenhofer et al. 2018", "haarpsi", 16),
    _Def("mdsi", "MDSI", LOWER, (0, None), "LHM: gradient on L, chroma on H and M",
         "Nafchi et al. 2016", "mdsi", 8),
)


ROUNDING = 1e-5
"""The most a score may pass its metric's range by float32 rounding."""


class IQAScorer(FrameScorer):
    def __init__(self, spec: MetricSpec, fn: Callable[..., Any]) -> None:
        self.spec = spec
        self.fn = fn

    def settings(self) -> dict[str, Any]:
        return {"frames": "mean", "input": "rgb01-float32"}

    def provenance(self) -> dict[str, Any]:
        from ..version import __version__

        return {"implementation": f"cgvqm_core {__version__} (PIQ 0.8 definitions)"}

    def score_frames(self, test: Any, ref: Any) -> np.ndarray:
        """Per-frame scores, held to the metric's registered range where they pass it by
        float rounding only (DSS gives 1.000002 on identical frames: 17 sub-band weights
        each with its epsilon); a larger excess is kept as computed."""
        values = self.fn(test, ref).double().cpu().numpy()
        lo, hi = self.spec.value_range
        if lo is not None:
            values = np.where((values < lo) & (values >= lo - ROUNDING), lo, values)
        if hi is not None:
            values = np.where((values > hi) & (values <= hi + ROUNDING), hi, values)
        return values


class IQAEntry(Entry):
    def __init__(self, d: _Def) -> None:
        self.d = d
        self.spec = MetricSpec(
            name=d.name, title=d.title, family="piq_family", direction=d.direction,
            value_range=d.value_range, kind=IMAGE, colour=d.colour, licence=PIQ_LICENCE,
            reference=d.reference, min_size=d.min_size)

    def build(self, options: MetricOptions) -> IQAScorer:
        from . import iqa

        return IQAScorer(self.spec, getattr(iqa, self.d.function))


ENTRIES: tuple[Entry, ...] = tuple(IQAEntry(d) for d in DEFS)
LISTING_GROUP = CLASSICAL_IMAGE
