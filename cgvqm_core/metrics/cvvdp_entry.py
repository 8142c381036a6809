"""ColorVideoVDP (Mantiuk et al. 2024) through the ``cvvdp`` package (MIT licence).

A video metric in JOD units (10 = no visible difference; higher is better) with a display
model: by default ColorVideoVDP's ``standard_4k``, the CGVQM paper's 'standard-4K', set by the
study's viewing condition (:mod:`.viewing`). Frames stream from the project's video source
through a ColorVideoVDP ``video_source`` (sRGB frames, the display model turns them into
luminance), so memory stays at ColorVideoVDP's sliding window, never a whole video.

How it is imported: ``pycvvdp/__init__`` imports the machine-learning variant (which downloads
weights from a model hub), the video-file reader (which needs a module named ``ffmpeg``, a
name two unrelated PyPI packages claim) and torchvision. None of that is needed here: the
metric module is loaded without running the package's ``__init__``, so the ML variant's
download code is never imported, and where torchvision cannot be imported its one used
function, ``GaussianBlur``, comes from :mod:`._gaussian_blur` (recorded in the provenance).
Install with ``pip install --no-deps cvvdp==0.5.7`` (its declared dependencies pull
torchvision and the clashing ``ffmpeg`` package; it needs only numpy, scipy and torch here).
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import sys
import types
from collections.abc import Iterator, Sequence
from typing import Any

from ..errors import CGVQMError
from ..stream import FrameSource, Geometry, _counted, aligned_frames
from .registry import (
    HIGHER,
    VIDEO,
    VIDEO_METRICS,
    Availability,
    Entry,
    MetricOptions,
    MetricScore,
    MetricSpec,
    VideoScorer,
    package_version,
)
from .standins import modules_replaced

log = logging.getLogger(__name__)
SUPPORTED = "0.5.7"

SPEC = MetricSpec(
    name="cvvdp", title="ColorVideoVDP", family="cvvdp_entry", direction=HIGHER,
    value_range=(None, 10), kind=VIDEO,
    colour="sRGB frames through the display model to linear luminance, DKL opponent space",
    licence="cvvdp: MIT (University of Cambridge)", reference="Mantiuk et al. 2024",
    outputs=("score",), min_size=16, reads=("viewing",))

_STATE: dict[str, Any] = {}


def _torchvision_blur_missing() -> bool:
    try:
        from torchvision.transforms import GaussianBlur  # noqa: F401
    except Exception:  # not installed, or broken beside this torch build
        return True
    return False


def _importable(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def _placeholder(name: str) -> types.ModuleType:
    """A module that only fails when used (ColorVideoVDP's writer imports, never used)."""
    mod = types.ModuleType(name)

    def missing(attr: str) -> Any:
        raise CGVQMError(f"{name}.{attr} is not available: cgvqm_core runs ColorVideoVDP "
                         "without its video writer")

    mod.__getattr__ = missing  # type: ignore[attr-defined]
    if name == "imageio":
        mod.__path__ = []  # type: ignore[attr-defined]  (a package, for imageio.v2)
    return mod


def load_cvvdp() -> tuple[Any, Any, bool]:
    """(cvvdp class, video_source_dm base class, stand-in blur used?)."""
    if "mod" in _STATE:
        return _STATE["mod"], _STATE["vs"], _STATE["standin"]
    spec = importlib.util.find_spec("pycvvdp")
    if spec is None or not spec.submodule_search_locations:
        raise CGVQMError("ColorVideoVDP is not installed: pip install --no-deps "
                         f"cvvdp=={SUPPORTED}")
    if "pycvvdp" not in sys.modules:
        pkg = types.ModuleType("pycvvdp")
        pkg.__path__ = list(spec.submodule_search_locations)  # type: ignore[attr-defined]
        pkg.__spec__ = spec
        pkg.__file__ = spec.origin
        sys.modules["pycvvdp"] = pkg
    standin = _torchvision_blur_missing()
    fakes: dict[str, types.ModuleType] = {}
    if standin:
        from . import _gaussian_blur

        tv = types.ModuleType("torchvision")
        tr = types.ModuleType("torchvision.transforms")
        tr.GaussianBlur = _gaussian_blur.GaussianBlur  # type: ignore[attr-defined]
        tv.transforms = tr  # type: ignore[attr-defined]
        fakes.update({"torchvision": tv, "torchvision.transforms": tr})
    # its channel-dump video writer imports these at module level; the metric never uses it
    for name in ("ffmpeg", "imageio", "imageio.v2"):
        if not _importable(name):
            fakes[name] = _placeholder(name)
    with modules_replaced(fakes):
        from pycvvdp import cvvdp_metric, video_source, vq_metric
    sys.modules["pycvvdp"].vq_exception = vq_metric.vq_exception  # used by its error paths
    _STATE.update(mod=cvvdp_metric.cvvdp, vs=video_source.video_source_dm, standin=standin)
    return _STATE["mod"], _STATE["vs"], standin


def streaming_source(base: type, ref: FrameSource, test: FrameSource, geom: Geometry,
                     display: Any) -> Any:
    """A ColorVideoVDP video source that hands out frames in order from the two streams."""
    import torch

    class _Stream(base):  # type: ignore[misc, valid-type]
        def __init__(self) -> None:
            super().__init__(display_photometry=display)
            self._its: list[Iterator[Any]] = [aligned_frames(test, geom, "test"),
                                              _counted(ref, "reference")]
            self._next = [0, 0]

        def get_video_size(self) -> tuple[int, int, int]:
            return geom.height, geom.width, geom.frames

        def get_frames_per_second(self) -> float:
            return geom.fps

        def _frame(self, which: int, index: int, device: Any, colorspace: str) -> Any:
            if index != self._next[which]:
                raise CGVQMError("ColorVideoVDP asked for frames out of order; this video "
                                 "source streams and cannot seek")
            self._next[which] += 1
            arr = next(self._its[which])
            t = torch.from_numpy(arr).to(device).permute(2, 0, 1)[None, :, None]
            t = t.to(torch.float32) / 255
            return self.apply_dm_and_color_transform(t, colorspace)

        def get_test_frame(self, frame: int, device: Any, colorspace: str) -> Any:
            return self._frame(0, frame, device, colorspace)

        def get_reference_frame(self, frame: int, device: Any, colorspace: str) -> Any:
            return self._frame(1, frame, device, colorspace)

        def drain(self) -> None:
            for it in self._its:
                for _ in it:
                    pass

    return _Stream()


class CvvdpScorer(VideoScorer):
    spec = SPEC

    def __init__(self, options: MetricOptions) -> None:
        import torch

        cls, self._vs, self.standin = load_cvvdp()
        from pycvvdp.display_model import vvdp_display_geometry

        self.viewing = options.viewing
        geometry = None
        if options.viewing.ppd is not None:
            geometry = vvdp_display_geometry((3840, 2160), ppd=options.viewing.ppd)
        self.device = torch.device(options.device)
        with contextlib.redirect_stdout(sys.stderr):
            self.metric = cls(display_name=options.viewing.display, display_geometry=geometry,
                              device=self.device, quiet=True, temp_padding="replicate")

    def settings(self) -> dict[str, Any]:
        return {"display": self.viewing.display, "ppd": round(self.metric.pix_per_deg, 4),
                "temporal_padding": "replicate"}

    def provenance(self) -> dict[str, Any]:
        return {"cvvdp": package_version("cvvdp"),
                "gaussian_blur": ("cgvqm_core stand-in (torchvision not importable)"
                                  if self.standin else "torchvision")}

    def score_video(self, ref: FrameSource, tests: Sequence[FrameSource], *,
                    progress: bool = False) -> list[list[MetricScore]]:
        import torch

        info = ref.info
        geom = Geometry(int(info.frame_count), int(info.height), int(info.width),
                        float(info.fps), 1)
        out = []
        for t in tests:
            src = streaming_source(self._vs, ref, t, geom, self.metric.display_photometry)
            with torch.inference_mode():
                jod, _stats = self.metric.predict_video_source(src)
            src.drain()
            out.append([MetricScore(self.name, SPEC.direction, float(jod))])
        return out


class CvvdpEntry(Entry):
    spec = SPEC

    def availability(self) -> Availability:
        try:
            found = importlib.util.find_spec("pycvvdp") is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            return Availability(False, "the cvvdp package is not installed (pip install "
                                       f"--no-deps cvvdp=={SUPPORTED})")
        version = package_version("cvvdp")
        if version != SUPPORTED:
            return Availability(False, f"cvvdp {version} is installed; this toolkit loads "
                                       f"cvvdp {SUPPORTED} (pip install --no-deps "
                                       f"cvvdp=={SUPPORTED})")
        return Availability(True)

    def build(self, options: MetricOptions) -> CvvdpScorer:
        return CvvdpScorer(options)


ENTRIES: tuple[Entry, ...] = (CvvdpEntry(),)
LISTING_GROUP = VIDEO_METRICS
