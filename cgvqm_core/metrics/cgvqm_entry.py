"""CGVQM-2 and CGVQM-5 as registry entries (the metric itself lives in :mod:`cgvqm_core.metric`).

One result per pooling asked for (max, as calibrated, or mean, as the upstream demo), with the
backbone and weights hashes; a random backbone or uniform weights are flagged in the metric
name (``-uniform``) and the ``backbone`` column (``random-seed-N``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .registry import (
    CGVQM_ITSELF,
    HIGHER,
    VIDEO,
    Availability,
    Entry,
    MetricOptions,
    MetricScore,
    MetricSpec,
    VideoScorer,
    module_available,
)

if TYPE_CHECKING:
    from ..metric import CGVQM


def metric_name(metric: CGVQM) -> str:
    """CGVQM's metric name: ``cgvqm-2`` / ``cgvqm-5`` for the published weights; other
    weights get a suffix, and seamless tiling (not upstream-identical) adds ``-seamless``."""
    w = metric.weights
    if w.kind == "upstream-pickle":
        name = metric.variant
    elif w.kind == "uniform":
        name = f"{metric.variant}-uniform"
    else:
        name = f"{metric.variant}-{Path(w.source).stem}"
    return f"{name}-seamless" if metric.seamless else name


def metric_title(metric: CGVQM) -> str:
    """The name prose prints: ``CGVQM-2``, with :func:`metric_name`'s suffix kept."""
    return metric.variant.upper() + metric_name(metric)[len(metric.variant):]


def _spec(variant: str, levels: str) -> MetricSpec:
    return MetricSpec(
        name=variant, title=variant.upper(), family="cgvqm_entry", direction=HIGHER,
        value_range=(None, 100), kind=VIDEO,
        colour="RGB normalised as Kinetics-400 (torchvision's mean and std)",
        licence="cgvqm_core (Apache-2.0); published weights IntelLabs/cgvqm (Apache-2.0); "
                "R3D-18 Kinetics-400 weights from torchvision (BSD-3-Clause)",
        reference=f"Jindal et al. 2025 ({levels})", needs_weights=True,
        outputs=("score", "per_frame", "per_clip", "error_map"), min_size=4,
        reads=("weights", "backbone", "random_backbone", "precision", "patch_scale",
               "batch_size", "seamless", "fast_stem", "pools"))


def cgvqm_settings(metric: Any) -> dict[str, Any]:
    """What a scores row's ``settings`` record of a CGVQM (batch and ``score --csv`` alike)."""
    p = metric.provenance()
    out = {"variant": p["variant"], "patch_scale": p["patch_scale"],
           "precision": p["precision"], "device": metric.net.device.type, "mode": p["mode"]}
    if metric.net.differences:  # bf16 numbers differ from the plain path's
        out["differences"] = True
    if metric.net.tf32_stem:  # so do those of fp16 with --fast-stem
        out["tf32_stem"] = True
    return out


def cgvqm_provenance(metric: Any) -> dict[str, Any]:
    """What the resume key and the CSV's ``versions`` record besides the settings: the
    toolkit's version too, since a release can change CGVQM's numbers."""
    p = metric.provenance()
    return {"backbone": p["backbone"]["label"], "backbone_sha256": p["backbone"]["sha256"],
            "weights_sha256": p["weights"]["sha256"], "torch": p["torch_version"],
            "cgvqm_core": p["cgvqm_core_version"]}


class CGVQMScorer(VideoScorer):
    def __init__(self, spec: MetricSpec, options: MetricOptions) -> None:
        from ..metric import CGVQM

        self.spec = spec
        self.pools = tuple(options.pools)
        self.metric = CGVQM(spec.name, weights=options.weights, backbone=options.backbone,
                            random_backbone=options.random_backbone, device=options.device,
                            precision=options.precision, patch_scale=options.patch_scale,
                            batch_size=options.batch_size, seamless=options.seamless,
                            tf32_stem=options.fast_stem)

    @property
    def name(self) -> str:
        return metric_name(self.metric)

    def settings(self) -> dict[str, Any]:
        return cgvqm_settings(self.metric)

    def provenance(self) -> dict[str, Any]:
        return cgvqm_provenance(self.metric)

    def not_applicable(self, height: int, width: int) -> str | None:
        if min(height, width) < self.metric.patch_scale:
            return (f"not applicable at {width}x{height}: patch scale "
                    f"{self.metric.patch_scale} leaves patches of 0 pixels")
        return None

    def score_video(self, ref: Any, tests: Sequence[Any], *,
                    progress: bool = False) -> list[list[MetricScore]]:
        # the engine opened and checked these sources with the user's --allow-resample and
        # --strict; checking them again here refused what the user allowed
        results = self.metric.score_many(ref, list(tests), pool=self.pools[0],
                                         allow_resample=True, progress=progress)
        prov = self.provenance()
        out = []
        for res in results:
            row = []
            for pool in self.pools:
                row.append(MetricScore(
                    self.name, self.spec.direction, res.quality(pool),
                    per_frame=[float(x) for x in _per_frame(res, pool)], pooling=pool,
                    extra={"patches": res.n_patches, "backbone": prov["backbone"],
                           "backbone_sha256": prov["backbone_sha256"],
                           "weights_sha256": prov["weights_sha256"],
                           "random_backbone": res.is_random_backbone}))
            out.append(row)
        return out


def _per_frame(res: Any, pool: str) -> list[float]:
    from ..metric import pool_errors

    flat = res.frame_errors.reshape(res.frame_errors.shape[0], -1)
    return [pool_errors(row, pool) for row in flat]


def _files_to_fetch(variant: str, options: MetricOptions) -> list[str]:
    """The published files this run would need but are in no cache: the variant's weights
    (unless the run gives its own) and the Kinetics-400 backbone (unless given, or random)."""
    import os

    from .. import hub, weights

    out = []
    v = weights.VARIANTS[variant]
    if options.weights is None and not any(p.is_file() for p in weights.candidates(v)):
        out.append("weights")
    if (options.random_backbone is None and not options.backbone
            and not os.environ.get(hub.BACKBONE_ENV) and not hub.hub_checkpoint_path().is_file()):
        out.append("backbone")
    return out


class CGVQMEntry(Entry):
    def __init__(self, variant: str, levels: str) -> None:
        self.spec = _spec(variant, levels)

    def availability(self) -> Availability:
        return self.availability_for(MetricOptions())

    def availability_for(self, options: MetricOptions) -> Availability:
        """Torch, and the published weights and the backbone unless the run gives its own:
        found in their caches, or fetchable (not with CGVQM_OFFLINE set). Files the run names
        are checked when the metric is built."""
        a = module_available("torch")
        if not a.ok:
            return a
        from .. import hub, weights

        missing = _files_to_fetch(self.spec.name, options)
        if not missing:
            return Availability(True)
        if not weights.offline():
            what = " and ".join({"weights": "the published weights",
                                 "backbone": "the R3D-18 backbone"}[m] for m in missing)
            return Availability(True, f"downloads {what} on first use")
        why = "not in the cache, and CGVQM_OFFLINE is set"
        if missing[0] == "weights":
            return Availability(False, weights.missing_message(
                weights.VARIANTS[self.spec.name], why))
        return Availability(False, hub.offline_message(
            "not in the torch hub cache, and CGVQM_OFFLINE is set"))

    def build(self, options: MetricOptions) -> CGVQMScorer:
        return CGVQMScorer(self.spec, options)


ENTRIES: tuple[Entry, ...] = (CGVQMEntry("cgvqm-2", "input, stem and layer1 of R3D-18"),
                              CGVQMEntry("cgvqm-5", "all five stages of R3D-18"))
LISTING_GROUP = CGVQM_ITSELF
