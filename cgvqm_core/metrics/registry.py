"""The metric registry: what each metric is (spec), whether it can run here, how to build it.

Every metric, CGVQM included, is an :class:`Entry` registered under a lower-case name; the
modules of this package declare their entries and the registry finds them (see "discovery"
below), so adding a metric is adding a module. An entry says what the metric is
(:class:`MetricSpec`: direction, range, kind, devices, weights, outputs, colour handling,
licence), whether it can run on this machine (:meth:`Entry.availability`,
with a one-line reason when not) and builds a :class:`Scorer` from the run's
:class:`MetricOptions`. Scorers come in two kinds: :class:`FrameScorer` (an image metric,
scored per frame and averaged over frames, the paper's protocol) and :class:`VideoScorer`
(a metric that reads the whole stream itself). Both read through :mod:`.engine`, the same
streaming source CGVQM uses.
"""

from __future__ import annotations

import importlib
import importlib.util
import pkgutil
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from ..errors import CGVQMError
from .viewing import ViewingCondition

HIGHER, LOWER = "higher-better", "lower-better"
IMAGE, VIDEO = "image", "video"


@dataclass(frozen=True)
class MetricSpec:
    """What a metric is; shown by ``cgvqm metrics`` and written with every score."""

    name: str
    title: str
    family: str  # the module that implements it
    direction: str  # HIGHER or LOWER
    value_range: tuple[float | None, float | None]
    kind: str  # IMAGE (per frame, mean over frames) or VIDEO
    colour: str  # what the metric sees of the RGB frames
    licence: str
    reference: str
    devices: tuple[str, ...] = ("cpu", "cuda")
    needs_weights: bool = False
    outputs: tuple[str, ...] = ("score", "per_frame")
    min_size: int = 1  # smallest height and width it is defined for
    #: the :class:`MetricOptions` fields, other than ``device``, that change its numbers;
    #: an option set for a run where no metric reads it is refused, not silently ignored
    reads: tuple[str, ...] = ()

    def range_text(self) -> str:
        lo, hi = self.value_range
        return f"{'-inf' if lo is None else f'{lo:g}'}..{'inf' if hi is None else f'{hi:g}'}"


@dataclass(frozen=True)
class Availability:
    ok: bool
    reason: str = ""


@dataclass
class MetricOptions:
    """Everything a run may set; each entry takes what concerns it."""

    device: str = "cpu"
    viewing: ViewingCondition = field(default_factory=ViewingCondition)
    # CGVQM
    weights: str | None = None
    backbone: str | None = None
    random_backbone: int | None = None
    precision: str = "auto"
    patch_scale: int = 4
    batch_size: int | None = None  # videos per network pass; None: the device's default
    seamless: bool = False
    fast_stem: bool = False  # fp16 on CUDA: the stem in TF32 (faster, further from fp32)
    pools: tuple[str, ...] = ("max",)
    # learned image metrics (LPIPS, DISTS, PieAPP): weights file per part (vgg16, lpips...),
    # folders holding them, and sha256s the user expects (see metrics.learned.files)
    learned_weights: dict[str, str] = field(default_factory=dict)
    learned_dirs: tuple[str, ...] = ()
    learned_sha256: dict[str, str] = field(default_factory=dict)


@dataclass
class MetricScore:
    """One metric's result for one test video."""

    metric: str
    direction: str
    score: float | None  # None when the metric does not apply (see ``note``)
    per_frame: list[float] | None = None
    pooling: str | None = None
    note: str = ""
    extra: dict[str, Any] = field(default_factory=dict)  # patches, backbone, hashes...

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"metric": self.metric, "score": self.score,
                               "direction": self.direction}
        if self.pooling:
            out["pooling"] = self.pooling
        if self.note:
            out["note"] = self.note
        if self.per_frame is not None:
            out["per_frame"] = self.per_frame
        out.update(self.extra)
        return out


class Scorer(ABC):
    """A metric ready to score, with the settings and provenance its numbers depend on."""

    spec: MetricSpec

    @property
    def name(self) -> str:
        """The metric name written in the scores file."""
        return self.spec.name

    @property
    def title(self) -> str:
        """The name prose and figures print (``PSNR``, ``CGVQM-2``); a variant's suffix
        (other weights, seamless tiling) is kept, so two metrics never share a title."""
        name, spec = self.name, self.spec
        return spec.title + name[len(spec.name):] if name.startswith(spec.name) else name

    def settings(self) -> dict[str, Any]:
        """Every option that changes the number (part of the resume key)."""
        return {}

    def provenance(self) -> dict[str, Any]:
        """Versions and hashes of what produced the number."""
        return {}

    def not_applicable(self, height: int, width: int) -> str | None:
        """Why the metric is undefined at this frame size, or None."""
        if min(height, width) < self.spec.min_size:
            return (f"not applicable at {width}x{height}: {self.spec.title} needs at least "
                    f"{self.spec.min_size}x{self.spec.min_size} pixels")
        return None


class FrameScorer(Scorer):
    """An image metric: one number per frame, the video's score is their mean."""

    @abstractmethod
    def score_frames(self, test: Any, ref: Any) -> np.ndarray:
        """(B,) float64 scores of test vs reference frames, both (B, 3, H, W) float in [0, 1]
        on the scorer's device."""


class VideoScorer(Scorer):
    """A metric that reads whole streams (temporal models, patch grids)."""

    @abstractmethod
    def score_video(self, ref: Any, tests: Sequence[Any], *, progress: bool = False
                    ) -> list[list[MetricScore]]:
        """Per test source, its results (one per pooling when a metric has several)."""


class Entry(ABC):
    """A registered metric: its spec, availability here, and a scorer factory."""

    spec: MetricSpec
    #: the local weight files it reads (:data:`.learned.files.PARTS`: vgg16, lpips, ...)
    weight_parts: tuple[str, ...] = ()

    def availability(self) -> Availability:
        return Availability(True)

    def availability_for(self, options: MetricOptions) -> Availability:
        """Availability for a run with these options (e.g. weight files given on the
        command line); by default the same as :meth:`availability`."""
        return self.availability()

    @abstractmethod
    def build(self, options: MetricOptions) -> Scorer: ...


def module_available(name: str, extra: str = "metric") -> Availability:
    """Available when ``name`` can be imported (found without importing it)."""
    try:
        found = importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        found = False
    if found:
        return Availability(True)
    return Availability(False, f"the {name} package is not installed "
                               f"(pip install 'cgvq-toolkit[{extra}]')")


def package_version(dist: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


# -- discovery ----------------------------------------------------------------------------
# A module of this package declares metrics with two module-level names: ``ENTRIES`` (a tuple
# of :class:`Entry`) and ``LISTING_GROUP`` (one of the groups below). The registry imports
# every public module and subpackage of the package the first time it is asked (helpers that
# should not be imported then are private, ``_name``) and lists the groups in this order, the
# modules of a group by name, and each module's entries in the order it declares them.
CLASSICAL_IMAGE = "classical image"
PERCEPTUAL_IMAGE = "perceptual image"
LEARNED_IMAGE = "learned image"
VIDEO_METRICS = "video"
CGVQM_ITSELF = "cgvqm"
LISTING_GROUPS = (CLASSICAL_IMAGE, PERCEPTUAL_IMAGE, LEARNED_IMAGE, VIDEO_METRICS, CGVQM_ITSELF)

_REGISTRY: dict[str, Entry] = {}
_LOADED = False


def _declaring_modules() -> list[ModuleType]:
    """The package's modules that declare ``ENTRIES``, in listing order."""
    package = importlib.import_module(__package__)
    found = []
    for info in pkgutil.iter_modules(package.__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__package__}.{info.name}")
        if not hasattr(module, "ENTRIES"):
            continue
        group = getattr(module, "LISTING_GROUP", None)
        if group not in LISTING_GROUPS:
            raise ValueError(f"{module.__name__} declares ENTRIES with LISTING_GROUP "
                             f"{group!r}, not one of {', '.join(LISTING_GROUPS)}")
        found.append(module)
    return sorted(found, key=lambda m: (LISTING_GROUPS.index(m.LISTING_GROUP), m.__name__))


def _load() -> None:
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    for module in _declaring_modules():
        for entry in module.ENTRIES:
            if entry.spec.name in _REGISTRY:
                raise ValueError(f"metric {entry.spec.name} registered twice")
            _REGISTRY[entry.spec.name] = entry


def entries() -> list[Entry]:
    """Every registered metric, in listing order (image metrics, video metrics, CGVQM last)."""
    _load()
    return list(_REGISTRY.values())


def metric_table_rows() -> list[dict[str, Any]]:
    """One plain-data row per registered metric, in listing order: its spec (name, title,
    direction, kind, range, devices, weights, outputs, colour, licence, reference) and whether
    it can run here (``available``, ``reason``). What ``cgvqm metrics`` prints and the docs'
    metric table are made from."""
    rows = []
    for e in entries():
        a, sp = e.availability(), e.spec
        rows.append({"name": sp.name, "title": sp.title, "direction": sp.direction,
                     "kind": sp.kind, "range": sp.range_text(), "devices": list(sp.devices),
                     "needs_weights": sp.needs_weights, "outputs": list(sp.outputs),
                     "colour": sp.colour, "licence": sp.licence, "reference": sp.reference,
                     "available": a.ok, "reason": a.reason})
    return rows


def get_entry(name: str) -> Entry:
    _load()
    key = name.strip().lower()
    if key not in _REGISTRY:
        raise CGVQMError(f"unknown metric {name!r}; `cgvqm metrics` lists them "
                         f"({', '.join(_REGISTRY)})")
    return _REGISTRY[key]


def parse_metric_list(text: str | Sequence[str],
                      options: MetricOptions | None = None) -> list[str]:
    """Names from 'a,b,c' (or a list of such), lower-cased, unique, in order; 'all' expands
    to every metric available (with ``options``, when given)."""
    parts = [text] if isinstance(text, str) else list(text)
    names: list[str] = []
    for part in parts:
        for n in str(part).split(","):
            n = n.strip().lower()
            if not n:
                continue
            if n == "all":
                names += [e.spec.name for e in entries()
                          if (e.availability_for(options) if options else e.availability()).ok]
            else:
                get_entry(n)
                names.append(n)
    if not names:
        raise CGVQMError("no metric named; `cgvqm metrics` lists them")
    return list(dict.fromkeys(names))


def check_device(device: str) -> None:
    """Refuse a device this PyTorch cannot use, in one line."""
    from ..devices import torch_device

    torch_device(device)


def readers(option: str, names: Sequence[str] | None = None) -> list[str]:
    """The metrics (of ``names``, or of the registry) that read the :class:`MetricOptions`
    field ``option``."""
    pool = [get_entry(n) for n in names] if names is not None else entries()
    return [e.spec.name for e in pool if option in e.spec.reads]


def build_scorers(names: Sequence[str], options: MetricOptions) -> list[Scorer]:
    """Scorers for the named metrics; an unavailable one is an error with its reason."""
    check_device(options.device)
    out = []
    for n in names:
        e = get_entry(n)
        a = e.availability_for(options)
        if not a.ok:
            raise CGVQMError(f"metric {e.spec.name} is not available here: {a.reason}")
        out.append(e.build(options))
    return out


def lazy(factory: Callable[[], Any]) -> Callable[[], Any]:
    """Memoised zero-argument factory (heavy imports happen on first use)."""
    cache: list[Any] = []

    def get() -> Any:
        if not cache:
            cache.append(factory())
        return cache[0]

    return get


def path_or_env(explicit: str | None, env: str) -> Path | None:
    import os

    value = explicit or os.environ.get(env)
    return Path(value).expanduser() if value else None
