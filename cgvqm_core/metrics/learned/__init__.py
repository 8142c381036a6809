"""LPIPS, DISTS and PieAPP: the learned image metrics of the CGVQM paper's comparison.

Their networks are this package's own PyTorch code (:mod:`.vgg`, :mod:`.alexnet`,
:mod:`.lpips`, :mod:`.dists`, :mod:`.pieapp`; torchvision is not needed) with PIQ 0.8's
definitions and defaults, the paper's protocol: per frame on RGB in [0, 1], then the mean
over frames. ``lpips`` is PIQ's LPIPS (VGG-16); ``lpips-alex`` is the LPIPS authors' default
network (AlexNet), for comparison with work that used their package. Weights come only from
local files (:mod:`.files`: options, environment variables, folders, the torch hub cache),
sha256-checked and read by PyTorch's allow-list loader; without them a metric is listed as
unavailable with the files it needs. Nothing is ever downloaded.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import CGVQMError
from ..registry import (
    IMAGE,
    LEARNED_IMAGE,
    LOWER,
    Availability,
    Entry,
    FrameScorer,
    MetricOptions,
    MetricSpec,
    module_available,
)
from . import files

#: frame pixels per network pass (LPIPS and DISTS hold a few VGG activations of this size)
PASS_PIXELS = 1 << 19


@dataclass(frozen=True)
class _Def:
    name: str
    title: str
    reference: str
    parts: tuple[str, ...]  # (feature network, head) or (whole network,)
    colour: str
    value_range: tuple[float | None, float | None]
    min_size: int
    definition: str
    settings: dict[str, Any] = field(default_factory=dict)


DEFS = (
    _Def("lpips", "LPIPS", "Zhang et al. 2018", ("vgg16", "lpips"),
         "RGB in [0, 1], ImageNet mean/std (= LPIPS's scaling layer); VGG-16 relu1_2..relu5_3",
         (0, None), 16, "PIQ 0.8 LPIPS (VGG-16, LPIPS v0.1 heads)",
         {"network": "vgg16", "heads": "lpips-v0.1"}),
    _Def("lpips-alex", "LPIPS (AlexNet)", "Zhang et al. 2018 (the authors' default network)",
         ("alexnet", "lpips-alex"),
         "RGB in [0, 1], ImageNet mean/std (= LPIPS's scaling layer); AlexNet relu1..relu5",
         (0, None), 31, "LPIPS v0.1 (AlexNet), PIQ's formulation",
         {"network": "alexnet", "heads": "lpips-v0.1"}),
    _Def("dists", "DISTS", "Ding et al. 2020", ("vgg16", "dists"),
         "RGB in [0, 1] resized to a shorter side of 256 when larger; ImageNet mean/std; "
         "VGG-16 with L2 pooling", (0, 1), 1, "PIQ 0.8 DISTS", {"resize_shorter_side": 256}),
    _Def("pieapp", "PieAPP", "Prashnani et al. 2018", ("pieapp",),
         "RGB in [0, 255], 64x64 patches at stride 27 (PIQ's default, the authors' sparse "
         "sampling)", (None, None), 64, "PIQ 0.8 PieAPP", {"patch": 64, "stride": 27}),
)


def _licence(d: _Def) -> str:
    return "; ".join(f"{files.PARTS[p].name} weights: {files.PARTS[p].licence}"
                     for p in d.parts) + "; code: cgvqm_core (PIQ's definitions, Apache-2.0)"


class LearnedScorer(FrameScorer):
    """A learned metric with its network on the run's device."""

    def __init__(self, spec: MetricSpec, d: _Def, weights: list[files.WeightsFile],
                 fn: Callable[[Any, Any], Any], per_pass: int | None) -> None:
        self.spec = spec
        self.d = d
        self.weights = weights
        self.fn = fn
        self.per_pass = per_pass  # frames per call, None = pixel budget

    def settings(self) -> dict[str, Any]:
        return {"frames": "mean", "input": "rgb01-float32", **self.d.settings}

    def provenance(self) -> dict[str, Any]:
        from ...version import __version__

        head = self.weights[-1]
        out: dict[str, Any] = {
            "implementation": f"cgvqm_core {__version__} ({self.d.definition})",
            "weights_sha256": head.sha256,
            "weights": {w.part.name: w.describe() for w in self.weights}}
        if len(self.weights) == 2:
            out["backbone"] = self.weights[0].path.name
            out["backbone_sha256"] = self.weights[0].sha256
        return out

    def score_frames(self, test: Any, ref: Any) -> np.ndarray:
        n, _, h, w = test.shape
        step = self.per_pass or max(1, PASS_PIXELS // max(1, h * w))
        out = [self.fn(test[i:i + step], ref[i:i + step]) for i in range(0, n, step)]
        return np.concatenate([o.double().cpu().numpy() for o in out])


def build_model(d: _Def, weights: list[files.WeightsFile], device: str
                ) -> tuple[Callable[[Any, Any], Any], int | None]:
    """The metric as a function of (test, reference) batches, on ``device``."""
    import torch

    dev = torch.device(device)
    if d.name == "pieapp":
        from .pieapp import PieAPPNet, pieapp

        net = PieAPPNet()
        shapes = {k: tuple(v.shape) for k, v in net.state_dict().items()}
        net.load_state_dict(files.pieapp_state(weights[0], shapes), strict=True)
        net = net.to(dev).eval().requires_grad_(False)
        chunk = 512 if dev.type == "cuda" else 64
        return (lambda t, r: pieapp(net, t, r, chunk=chunk)), 1
    backbone, head = weights
    if d.parts[0] == "alexnet":
        from . import alexnet as arch

        features = arch.make_features()
        full = arch.expected_keys()
    else:
        from . import vgg as arch  # type: ignore[no-redef]

        pool = None
        if d.name == "dists":
            from .dists import L2Pool

            pool = L2Pool
        features = arch.make_features(pool)
        full = arch.expected_keys()
    features.load_state_dict(files.features_state(backbone, full), strict=True)
    if d.name == "dists":
        from .dists import CHANNELS, DISTS

        alpha, beta = files.dists_alpha_beta(head, sum(CHANNELS))
        model: Any = DISTS(features, alpha, beta)
    else:
        from .lpips import LPIPS

        model = LPIPS(features, arch.TAPS, files.lpips_heads(head, arch.TAP_CHANNELS))
    model = model.to(dev).eval().requires_grad_(False)
    return model, None


class LearnedEntry(Entry):
    def __init__(self, d: _Def) -> None:
        self.d = d
        self.weight_parts = tuple(d.parts)
        self.spec = MetricSpec(
            name=d.name, title=d.title, family="learned", direction=LOWER,
            value_range=d.value_range, kind=IMAGE, colour=d.colour, licence=_licence(d),
            reference=d.reference, needs_weights=True, outputs=("score", "per_frame"),
            min_size=d.min_size,
            reads=("learned_weights", "learned_dirs", "learned_sha256"))

    def availability(self) -> Availability:
        return self.availability_for(MetricOptions())

    def availability_for(self, options: MetricOptions) -> Availability:
        a = module_available("torch")
        if not a.ok:
            return a
        missing = []
        try:
            for p in self.d.parts:
                if files.locate(p, options.learned_weights, options.learned_dirs) is None:
                    missing.append(files.how_to_give(files.PARTS[p]))
        except CGVQMError as exc:
            return Availability(False, str(exc))
        if missing:
            return Availability(False, "needs local weights, nothing is downloaded: "
                                       + "; ".join(missing))
        return Availability(True)

    def build(self, options: MetricOptions) -> LearnedScorer:
        weights = [files.load(p, options.learned_weights, options.learned_dirs,
                              options.learned_sha256) for p in self.d.parts]
        fn, per_pass = build_model(self.d, weights, options.device)
        return LearnedScorer(self.spec, self.d, weights, fn, per_pass)


ENTRIES: tuple[Entry, ...] = tuple(LearnedEntry(d) for d in DEFS)
LISTING_GROUP = LEARNED_IMAGE
