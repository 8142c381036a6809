"""The CGVQM metric object and its result record.

``CGVQM("cgvqm-2").score(ref, test)`` returns a :class:`CGVQMResult`: the quality q on the
0..100 impairment scale (100 - pooled patch error, unclamped as upstream), its label, the
pooling used, per-patch, per-clip and per-frame errors and the provenance (versions, sha256
of weights and backbone). ``score_many`` scores several test videos against one reference,
running the reference through the network once per patch.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from .emap import EmapRecorder, EmapVideoWriter, fit_tone_curve
from .errors import CGVQMError
from .features import FeatureNet
from .hub import Backbone, resolve_backbone
from .patch_scorer import PatchScorer
from .precision import cpu_name
from .scale_anchor import anchoring_for, apply_anchor
from .stage_clock import StageClock
from .stream import (
    StreamOutput,
    VideoInput,
    as_video_list,
    check_fps,
    check_frame_count,
    open_input,
    patch_channel_msd,
    reference_geometry,
    run,
)
from .version import __version__
from .weights import FeatureWeights, resolve_weights

log = logging.getLogger(__name__)

Pooling = Literal["max", "mean"]
POOLINGS: tuple[str, ...] = ("max", "mean")
LABELS = ("very annoying", "annoying", "slightly annoying", "perceptible but not annoying",
          "imperceptible")


def quality_label(q: float) -> str:
    """The impairment label of q: round(q / 25), clamped to the five labels."""
    if not np.isfinite(q):
        raise CGVQMError(f"q must be a finite number to have a label, got {q}")
    return LABELS[int(np.clip(np.round(q / 25.0), 0, len(LABELS) - 1))]


def pool_errors(errors: np.ndarray, pool: str) -> float:
    """q = 100 - max (or mean) of patch errors."""
    if pool == "max":
        return float(100.0 - np.max(errors))
    if pool == "mean":
        return float(100.0 - np.mean(errors))
    raise CGVQMError(f"unknown pooling {pool!r}; choose max or mean")


@dataclass
class CGVQMResult:
    """One test video's score against its reference."""

    q: float
    pool: str
    variant: str
    patch_errors: np.ndarray  # (n_clips, n_rows, n_cols)
    frame_errors: np.ndarray  # (frames, n_rows, n_cols): per-frame patch errors
    msd: np.ndarray  # (n_patches, N) per-channel mean squared differences
    seconds: float
    provenance: dict[str, Any]
    emap: np.ndarray | None = None  # (frames, H, W) when asked for as an array
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return quality_label(self.q)

    @property
    def n_patches(self) -> int:
        return int(self.patch_errors.size)

    def quality(self, pool: str) -> float:
        """q under either pooling (both come from the same patch errors)."""
        return pool_errors(self.patch_errors, pool)

    @property
    def per_clip(self) -> list[float]:
        """q of every clip (its patches pooled the same way as q)."""
        flat = self.patch_errors.reshape(self.patch_errors.shape[0], -1)
        return [pool_errors(row, self.pool) for row in flat]

    @property
    def per_frame(self) -> list[float]:
        """q of every frame, from each patch's per-frame error, pooled like q."""
        flat = self.frame_errors.reshape(self.frame_errors.shape[0], -1)
        return [pool_errors(row, self.pool) for row in flat]

    @property
    def q_anchored(self) -> float | None:
        """q on the study's 0..100 scale, when the weights carry a calibration anchoring
        fitted for this pooling (``cgvqm calibrate``); otherwise None."""
        weights_prov = self.provenance.get("weights", {}).get("provenance")
        anchor = anchoring_for(weights_prov, self.pool)
        return None if anchor is None else float(apply_anchor(anchor, self.q))

    @property
    def is_random_backbone(self) -> bool:
        return self.provenance.get("backbone", {}).get("random_seed") is not None

    @property
    def is_uniform_weights(self) -> bool:
        return self.provenance.get("weights", {}).get("kind") == "uniform"

    def to_dict(self, *, patches: bool = True) -> dict[str, Any]:
        """A JSON-ready record (the CLI's --json output)."""
        prov = self.provenance
        out: dict[str, Any] = {
            "q": self.q,
            "label": self.label,
            "variant": self.variant,
            "pool": self.pool,
            "q_max": self.quality("max"),
            "q_mean": self.quality("mean"),
            "per_clip": self.per_clip,
            "per_frame": self.per_frame,
            "n_patches": self.n_patches,
            "seconds": round(self.seconds, 3),
            "backbone": prov["backbone"]["label"],
            "backbone_sha256": prov["backbone"]["sha256"],
            "weights_sha256": prov["weights"]["sha256"],
            "random_backbone": self.is_random_backbone,
        }
        anchored = self.q_anchored
        if anchored is not None:
            out["q_anchored"] = anchored
            out["label_anchored"] = quality_label(anchored)
        if prov.get("precision", "fp32") != "fp32":
            out["precision"] = f"{prov['precision']} on {prov['device']} (not bit-exact)"
        if prov.get("mode") == "seamless":
            out["mode"] = "seamless (not upstream-identical)"
        flags = []
        if self.is_random_backbone:
            flags.append(f"a RANDOM backbone ({prov['backbone']['label']})")
        if self.is_uniform_weights:
            flags.append("UNIFORM feature weights")
        out["uniform_weights"] = self.is_uniform_weights
        if flags:
            out["warning"] = f"computed with {' and '.join(flags)}: not a CGVQM score"
        if patches:
            out["patch_errors"] = self.patch_errors.tolist()
        out["provenance"] = prov
        return out


#: feature settings a calibrated weights file must share with the metric that uses it
#: (the precision is left out: precisions agree to about 1e-3 in q, see docs/performance.md)
MATCHED_SETTINGS = ("variant", "n_channels", "backbone_sha256", "patch_scale", "mode")


def _shown_setting(key: str, value: Any) -> str:
    text = f"{value}"[:12] + "..." if key == "backbone_sha256" else f"{value}"
    return f"{key.replace('_', ' ')} {text}"


def check_calibration_settings(weights: FeatureWeights, own: Mapping[str, Any]) -> None:
    """Refuse calibrated weights under feature settings they were not fitted for, and show
    the file's own warning (e.g. a random backbone).

    omega/alpha weigh one backbone's channels at one patch grid, and the anchoring maps that
    q distribution; under other features both give a number on no calibrated scale. Files
    without ``feature_settings`` (the published pickles, hand-made files) are not checked.
    """
    prov = weights.provenance if isinstance(weights.provenance, dict) else {}
    fitted = prov.get("feature_settings")
    if isinstance(fitted, dict):
        diff = [k for k in MATCHED_SETTINGS if k in fitted and fitted[k] != own.get(k)]
        if diff:
            name = Path(str(weights.source)).name
            theirs = ", ".join(_shown_setting(k, fitted[k]) for k in diff)
            ours = ", ".join(_shown_setting(k, own.get(k)) for k in diff)
            raise CGVQMError(f"{name} was calibrated with {theirs}, but this metric uses "
                             f"{ours}: its weights and anchoring do not apply to these "
                             "features; score with the calibration's settings (its backbone, "
                             "--patch-scale and --seamless or not) or calibrate again")
    if prov.get("warning"):
        log.warning("weights %s: %s", Path(str(weights.source)).name, prov["warning"])


def _device_name(device: torch.device) -> str:
    """What ran the network: the GPU's name, or the CPU's model and thread count."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    if device.type == "cpu":
        return f"{cpu_name()}, {torch.get_num_threads()} threads"
    return device.type


class CGVQM:
    """CGVQM-2 or CGVQM-5 with a backbone and feature weights, ready to score.

    ``variant`` names the published weights; ``weights`` overrides them with a file (upstream
    pickle or project JSON; the variant then follows from the file) or ``"uniform"``.
    ``backbone`` is a state dict file or mapping (default: $CGVQM_BACKBONE, the torch hub
    cache, a download); ``random_backbone=SEED`` uses a seeded random network and marks every
    result. ``precision`` is ``auto`` (default: ``fp32`` on CPU, upstream-identical; ``tf32``
    on CUDA, upstream's numbers as it runs there), ``fp32`` (strict, CPU-equal also on CUDA),
    ``bf16`` (CPUs with AMX/AVX512-BF16 and GPUs), ``fp16`` or ``tf32`` (GPUs): faster, not
    bit-exact
    (:mod:`.precision`; the measured drift is in docs/performance.md); ``fp32_stem`` (default) keeps
    the stem in fp32 under bf16/fp16, which removes most of the drift; ``differences``
    (default: on for bf16) carries each test's activations as exact differences from its
    reference's (:mod:`.ref_delta`), which removes most of the rest. ``tf32_stem``,
    ``fused``, ``pad_stem``, ``split_stem``, ``stem_2d`` and ``stem_s2d`` are GPU speed-ups
    (:class:`~.features.FeatureNet`).
    ``seamless=True`` runs patches with a halo so features do not depend on the patch grid
    (:mod:`.seamless`; not upstream-identical, marked ``mode: seamless``, no error maps).
    ``batch_size`` is videos per network pass (default on a CPU: 2 for patches up to
    16x128x128 or in bf16, else 1; on CUDA as many as fit 16 patches of 30x128x128, so that several
    patch positions share a pass; :func:`~.patch_scorer.default_batch_size`); ``prefetch``
    decodes the next clip in a thread while the current one is scored (default: on CUDA
    only). Neither changes the numbers beyond float rounding.
    """

    def __init__(
        self,
        variant: str | None = None,
        *,
        weights: str | Path | FeatureWeights | None = None,
        backbone: str | Path | Backbone | Mapping[str, torch.Tensor] | None = None,
        random_backbone: int | None = None,
        device: str = "cpu",
        precision: str = "auto",
        patch_scale: int = 4,
        batch_size: int | None = None,
        prefetch: bool | None = None,
        fuse_bn: bool | None = None,
        cudnn_benchmark: bool = True,
        channels_last: bool | None = None,
        allow_download: bool = True,
        seamless: bool = False,
        fp32_stem: bool = True,
        differences: bool | None = None,
        tf32_stem: bool = False,
        fused: bool | None = None,
        pad_stem: bool | None = None,
        split_stem: str | None = None,
        stem_2d: bool = False,
        stem_s2d: bool = False,
    ) -> None:
        self.weights = resolve_weights(weights, variant or "cgvqm-2",
                                       allow_download=allow_download)
        self.variant = self.weights.variant
        if variant is not None and weights is not None and self.variant != variant:
            raise CGVQMError(f"variant {variant} asked for, but the weights are {self.variant}'s;"
                             " leave the variant out (it follows the weights) or pass its "
                             "weights")
        if isinstance(patch_scale, bool) or int(patch_scale) != patch_scale or patch_scale < 1:
            raise CGVQMError(f"patch scale must be a whole number of at least 1, got "
                             f"{patch_scale!r}")
        if batch_size is not None and batch_size < 1:
            raise CGVQMError(f"batch size (videos per network pass) must be at least 1, "
                             f"got {batch_size}")
        self.backbone = resolve_backbone(backbone, random_seed=random_backbone,
                                         allow_download=allow_download)
        self.patch_scale = int(patch_scale)
        self.seamless = bool(seamless)
        self.prefetch = prefetch
        check_calibration_settings(self.weights, self.feature_settings())
        self.net = FeatureNet(self.backbone, self.weights.n_levels, device=device,
                              precision=precision, fuse_bn=fuse_bn, channels_last=channels_last,
                              cudnn_benchmark=cudnn_benchmark,
                              fp32_stem=fp32_stem, differences=differences,
                              tf32_stem=tf32_stem, fused=fused, pad_stem=pad_stem,
                              split_stem=split_stem, stem_2d=stem_2d, stem_s2d=stem_s2d)
        self.scorer = PatchScorer(self.net, self.weights.level_weights(), self.weights.alpha,
                                  batch_size=batch_size)
        self._omega_abs = np.abs(self.weights.omega).astype(np.float64)

    # -- provenance ---------------------------------------------------------------------
    def feature_settings(self) -> dict[str, Any]:
        """The settings that decide the features m, in the keys a calibration records them
        under (``provenance.feature_settings`` of its weights file)."""
        return {"variant": self.variant, "n_channels": int(self.weights.omega.size),
                "backbone_sha256": self.backbone.sha256, "patch_scale": self.patch_scale,
                "mode": "seamless" if self.seamless else "upstream"}

    def provenance(self) -> dict[str, Any]:
        bb, w = self.backbone, self.weights
        return {
            "metric": "cgvqm",
            "cgvqm_core_version": __version__,
            "torch_version": torch.__version__,
            "numpy_version": np.__version__,
            "variant": self.variant,
            "n_levels": w.n_levels,
            "patch_scale": self.patch_scale,
            "device": str(self.net.device),
            "device_name": _device_name(self.net.device),
            "precision": self.net.precision,
            "precision_detail": dict(self.net.precision_info),
            "channels_last": self.net.channels_last,
            "mode": "seamless" if self.seamless else "upstream",
            "backbone": {"arch": bb.arch, "label": bb.label, "source": bb.source,
                         "sha256": bb.sha256, "random_seed": bb.random_seed},
            "weights": {"kind": w.kind, "source": w.source, "sha256": w.sha256,
                        "alpha": w.alpha, "provenance": w.provenance},
        }

    # -- scoring ------------------------------------------------------------------------
    def score(self, ref: VideoInput, test: VideoInput, *, pool: str = "max",
              fps: float | None = None, allow_resample: bool = False,
              emap: bool | str | Path = False, emap_png_dir: str | Path | None = None,
              on_conversion: str = "warn", progress: bool = False,
              strict: bool = False, clock: StageClock | None = None) -> CGVQMResult:
        """Score one test video against its reference.

        ``emap=True`` returns the error map as an array in the result (memory: frames x H x W
        float32); ``emap=PATH`` writes the heat-map video (.mp4 or .mkv) streamed instead;
        ``emap_png_dir`` also writes one PNG per frame. ``strict`` refuses a test whose frame
        count differs from the reference's (by default it is resampled in time, with a
        warning saying how many frames were invented or dropped).
        """
        return self.score_many(ref, [test], pool=pool, fps=fps, allow_resample=allow_resample,
                               emap=[emap], emap_png_dirs=[emap_png_dir],
                               on_conversion=on_conversion, progress=progress,
                               strict=strict, clock=clock)[0]

    def score_many(self, ref: VideoInput, tests: Sequence[VideoInput], *, pool: str = "max",
                   fps: float | None = None, allow_resample: bool = False,
                   emap: Sequence[bool | str | Path] | None = None,
                   emap_png_dirs: Sequence[str | Path | None] | None = None,
                   on_conversion: str = "warn", progress: bool = False,
                   strict: bool = False, clock: StageClock | None = None
                   ) -> list[CGVQMResult]:
        """Score several test videos that share ``ref``; its features are computed once.

        ``clock`` (:class:`~cgvqm_core.stage_clock.StageClock`) adds up where the time went.
        """
        if pool not in POOLINGS:
            raise CGVQMError(f"unknown pooling {pool!r}; choose max or mean")
        t0 = time.perf_counter()
        tests = as_video_list(tests)
        rsrc = open_input(ref, fps=fps, name="reference", on_conversion=on_conversion)
        geom = reference_geometry(rsrc, self.patch_scale)
        tsrcs = [open_input(t, fps=fps, name=f"test {i}", on_conversion=on_conversion,
                            array_fps=geom.fps) for i, t in enumerate(tests)]
        for t in tsrcs:
            check_fps(rsrc, t, allow_resample)
            check_frame_count(rsrc, t, strict)
        emap = list(emap) if emap is not None else [False] * len(tests)
        pngs = list(emap_png_dirs) if emap_png_dirs is not None else [None] * len(tests)
        if self.seamless and (any(emap) or any(pngs)):
            raise CGVQMError("error maps are not offered in seamless mode")
        sinks, closers, recorders = [], [], {}
        for i, (em, png) in enumerate(zip(emap, pngs, strict=True)):
            if em is True:
                recorders[i] = EmapRecorder(geom)
                sinks.append(recorders[i])
            elif em or png:
                curve = fit_tone_curve(open_input(tests[i], fps=fps, array_fps=geom.fps,
                                                  on_conversion=on_conversion), geom)
                writer = EmapVideoWriter(em or None, png, geom.fps, curve)
                sinks.append(writer)
                closers.append(writer)
            else:
                sinks.append(None)
        try:
            outs = run(rsrc, tsrcs, self.scorer, geom, emap_sinks=sinks, progress=progress,
                       desc=f"{self.variant} {Path(str(rsrc.info.path)).name}",
                       seamless=self.seamless, prefetch=self.prefetch, clock=clock)
        finally:
            for w in closers:
                w.close()
        seconds = (time.perf_counter() - t0) / max(len(tests), 1)
        prov = self.provenance()
        prov["reference"] = {"path": str(rsrc.info.path), "width": geom.width,
                             "height": geom.height, "frames": geom.frames, "fps": geom.fps}
        prov["clip_len"], prov["grid"] = geom.clip_len, [geom.n_rows, geom.n_cols]
        results = []
        for i, out in enumerate(outs):
            p = dict(prov)
            info = tsrcs[i].info
            p["test"] = {"path": str(info.path), "width": info.width, "height": info.height,
                         "frames": info.frame_count, "fps": info.fps,
                         "resized": (info.width, info.height) != (geom.width, geom.height),
                         "resampled": info.frame_count != geom.frames}
            res = self._result(out, pool, seconds, p)
            if i in recorders:
                res.emap = recorders[i].array()
            results.append(res)
        return results

    def _result(self, out: StreamOutput, pool: str, seconds: float,
                prov: dict[str, Any]) -> CGVQMResult:
        g = out.geometry
        errors = self.weights.alpha * (out.msd.astype(np.float64) @ self._omega_abs)
        patch_errors = errors.reshape(g.n_clips, g.n_rows, g.n_cols)
        assert out.series is not None
        frame_errors = out.series.transpose(0, 3, 1, 2).reshape(-1, g.n_rows, g.n_cols)
        frame_errors = frame_errors[: g.frames].astype(np.float64)
        return CGVQMResult(pool_errors(errors, pool), pool, self.variant, patch_errors,
                           frame_errors, out.msd, seconds, prov)

    def channel_msd(self, ref: VideoInput, tests: Sequence[VideoInput], **kw: Any
                    ) -> list[StreamOutput]:
        """:func:`patch_channel_msd` with this metric's network and patch grid."""
        return patch_channel_msd(ref, tests, self.net, patch_scale=self.patch_scale,
                                 batch_size=self.scorer.batch_size, seamless=self.seamless,
                                 **kw)
