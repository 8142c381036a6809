"""Calibration from datasets to a weights file: cache, validate, fit, anchor, save."""

from __future__ import annotations

import datetime as _dt
import hashlib
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..errors import CGVQMError
from ..scale_anchor import apply_anchor
from ..version import __version__
from ..weights import VARIANTS, FeatureWeights, save_weights
from .anchoring import fit_anchor, refit_alpha
from .cache import FeatureCache, FeatureFn, JobRunner, pack
from .data import DatasetSpec, load_datasets
from .fitting import FitConfig, FitResult, fit, pooled_errors
from .splits import scene_split
from .stats import correlations
from .validation import (
    HONESTY_NOTE,
    SELECTION_NOTE,
    CalibrationData,
    ValidationResult,
    validate,
    wrong_scale_note,
)

log = logging.getLogger(__name__)


@dataclass
class FeatureSource:
    """How m is computed: the metric's network (or any function, e.g. in tests)."""

    compute: FeatureFn
    settings: dict[str, Any]  # variant, n_channels, backbone_sha256, ... (the cache key)
    backbone: dict[str, Any] = field(default_factory=dict)  # provenance of the backbone
    supersets: list[dict[str, Any]] = field(default_factory=list)  # caches to slice from
    runner: JobRunner | None = None  # computes the jobs elsewhere (Ray) instead of compute


def metric_features(variant: str, *, backbone: str | Path | None = None,
                    random_backbone: int | None = None, device: str = "cpu",
                    precision: str = "fp32", patch_scale: int = 4, batch_size: int | None = None,
                    allow_resample: bool = False, on_conversion: str = "warn"
                    ) -> FeatureSource:
    """The metric's per-patch channel MSD (:meth:`cgvqm_core.metric.CGVQM.channel_msd`)."""
    from ..metric import CGVQM  # the network is only built when features are needed

    n = VARIANTS[variant].n_channels
    # omega does not enter m; this placeholder only satisfies the metric's constructor
    placeholder = FeatureWeights(variant, np.full(n, 1.0 / n, dtype=np.float32), 1.0, "none",
                                 "calibration features", "features-only")
    metric = CGVQM(variant, weights=placeholder, backbone=backbone, random_backbone=random_backbone,
                   device=device, precision=precision, patch_scale=patch_scale,
                   batch_size=batch_size)
    bb = metric.backbone

    def compute(ref: str, tests: Sequence[str]) -> list[np.ndarray]:
        outs = metric.channel_msd(ref, list(tests), allow_resample=allow_resample,
                                  on_conversion=on_conversion)
        return [o.msd for o in outs]

    settings = {"variant": variant, "n_channels": VARIANTS[variant].n_channels,
                "backbone_sha256": bb.sha256, "patch_scale": int(patch_scale),
                "precision": precision, "mode": "upstream"}
    prov = {"arch": bb.arch, "label": bb.label, "sha256": bb.sha256, "source": bb.source,
            "random_seed": bb.random_seed}
    supersets = [{**settings, "variant": name, "n_channels": v.n_channels}
                 for name, v in VARIANTS.items() if v.n_channels > settings["n_channels"]]
    return FeatureSource(compute, settings, prov, supersets)


def build_data(items: pd.DataFrame, source: FeatureSource, cache_root: str | Path, *,
               show_progress: bool = True) -> CalibrationData:
    """Fill the cache for ``items`` and pack the features for fitting."""
    cache = FeatureCache(cache_root, source.settings,
                         supersets=[FeatureCache(cache_root, s) for s in source.supersets])
    arrays = cache.build(items, source.compute, show_progress=show_progress,
                         runner=source.runner)
    M, counts = pack(arrays)
    return CalibrationData(items.reset_index(drop=True), M, counts)


@dataclass
class CalibrationOutcome:
    weights: FeatureWeights
    final: FitResult
    validation: ValidationResult | None
    train_correlations: dict[str, dict[str, float]]
    path: Path | None = None
    warnings: list[str] = field(default_factory=list)
    """About the final fit (with or without validation): e.g. scores that fall as the human
    scores rise."""


def _file_sha(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def fit_final(data: CalibrationData, config: FitConfig, *, val_ratio: float, seed: int
              ) -> tuple[FitResult, np.ndarray, np.ndarray]:
    """Fit on all scenes (minus validation scenes when selecting by validation loss)."""
    if config.select == "val":
        split = scene_split(data.items["scene"].astype(str).tolist(),
                            data.items["dataset"].astype(str).tolist(), 1.0, seed,
                            val_ratio=val_ratio)
        train, val = split.train, split.val
    else:
        train, val = np.ones(len(data.items), bool), np.zeros(len(data.items), bool)
    res = fit(data.M, data.counts, data.y, data.groups, train[None],
              val=val[None] if config.select == "val" else None, config=config)
    return res, train, val


def calibrate(data: CalibrationData, variant: str, config: FitConfig, *,
              train_ratios: Sequence[float] = (0.2,), repeats: int = 10, seed: int = 0,
              val_ratio: float = 0.25, anchor: str = "logistic", validation: bool = True,
              datasets: Sequence[DatasetSpec] = (), dmos_scale: str = "quality",
              feature_settings: dict[str, Any] | None = None,
              backbone: dict[str, Any] | None = None, out: str | Path | None = None
              ) -> CalibrationOutcome:
    """Validate with repeated scene-disjoint splits, fit the final weights on all scenes,
    refit alpha, anchor the scale, and (with ``out``) save a ``cgvqm-weights/1`` file."""
    n_ch = VARIANTS[variant].n_channels
    if data.M.shape[2] != n_ch:
        raise CGVQMError(f"features have {data.M.shape[2]} channels; {variant} needs {n_ch}")
    seeds = [seed + i for i in range(repeats)]
    val_res = None
    if validation:
        val_res = validate(data, train_ratios, seeds, replace(config, seed=seed),
                           val_ratio=val_ratio, anchor=anchor, dmos_scale=dmos_scale)
    final, train, val = fit_final(data, replace(config, seed=seed), val_ratio=val_ratio,
                                  seed=seed)
    omega = final.omega[0]
    E = pooled_errors(data.M, data.counts, omega, config.pooling)
    fit_set = train | val
    alpha = refit_alpha(E[fit_set], data.y[fit_set])
    q = 100.0 - alpha * E
    anchoring = None if anchor == "none" else fit_anchor(q[fit_set], data.y[fit_set], anchor,
                                                         pool=config.pooling)
    train_corr = {}
    for d in data.dataset_names:
        sel = fit_set & (data.items["dataset"].to_numpy() == d)
        c = correlations(q[sel], data.y[sel])
        if anchoring is not None:
            c["rmse_anchored"] = float(np.sqrt(np.mean(
                (apply_anchor(anchoring, q[sel]) - data.y[sel]) ** 2)))
        train_corr[d] = c
    prov = _provenance(data, variant, config, final, train, val, alpha, anchoring, train_corr,
                       val_res, seeds, train_ratios, val_ratio, datasets, dmos_scale,
                       feature_settings, backbone, validation)
    weights = FeatureWeights(variant, omega.astype(np.float32), float(alpha), "",
                             str(out) if out else "calibration", "project", prov)
    path = save_weights(out, weights) if out is not None else None
    falling = [d for d, c in train_corr.items() if np.isfinite(c["plcc"]) and c["plcc"] < 0]
    warnings = [f"the final fit's scores correlate NEGATIVELY with the human scores "
                f"({', '.join(falling)}): " + wrong_scale_note(dmos_scale)] if falling else []
    return CalibrationOutcome(weights, final, val_res, train_corr, path, warnings)


def _provenance(data, variant, config, final, train, val, alpha, anchoring, train_corr,
                val_res, seeds, train_ratios, val_ratio, datasets, dmos_scale,
                feature_settings, backbone, validation) -> dict[str, Any]:
    items = data.items
    ds_info = []
    for spec in datasets:
        sel = items["dataset"] == spec.name
        ds_info.append({"name": spec.name, "manifest": str(spec.manifest),
                        "manifest_sha256": _file_sha(spec.manifest),
                        "dmos_csv": str(spec.dmos_csv), "dmos_sha256": _file_sha(spec.dmos_csv),
                        "n_videos": int(sel.sum()),
                        "n_scenes": int(items.loc[sel, "scene"].nunique())})
    if not ds_info:
        for d in data.dataset_names:
            sel = items["dataset"] == d
            ds_info.append({"name": d, "n_videos": int(sel.sum()),
                            "n_scenes": int(items.loc[sel, "scene"].nunique())})
    prov: dict[str, Any] = {
        "tool": "cgvqm calibrate",
        "cgvqm_core_version": __version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "variant": variant,
        "pool": config.pooling,
        "datasets": ds_info,
        "target": ("clip(DMOS, 0, 100) (quality scale)" if dmos_scale == "quality"
                   else "100 - clip(DMOS, 0, 100) (DMOS given on an impairment scale)"),
        "objective": {"plcc": "sum over datasets of 1 - |PLCC(s, target)| (upstream)",
                      "plcc-signed": "sum over datasets of 1 - PLCC(q, target)",
                      "nmse": "sum over datasets of MSE(q, target) / var(target)"}[
                          config.objective],
        "optimiser": {"name": "Adam", "steps": config.steps, "lr_omega": config.lr_omega,
                      "lr_alpha": config.lr_alpha, "alpha_init": config.alpha_init,
                      "betas": list(config.betas), "init_seed": config.seed,
                      "omega_init": "uniform random, normalised to sum 1"},
        "selection": SELECTION_NOTE[config.select],
        "final_fit": {
            "videos": int(train.sum()), "validation_videos": int(val.sum()),
            "scenes": "all scenes" + (" (validation scenes held out)" if val.any() else ""),
            "best_step": int(final.best_step[0]), "best_loss": float(final.best_loss[0]),
            "alpha_from_optimiser": float(final.alpha[0]),
            "alpha": "refitted by least squares on the fitted videos (q = 100 - alpha * e)",
            "correlations_on_fitted_videos": train_corr,
        },
        "anchoring": anchoring,
        "backbone": backbone or {},
        "feature_settings": feature_settings or {},
    }
    if backbone and backbone.get("random_seed") is not None:
        prov["warning"] = ("fitted on features of a RANDOM backbone (seed "
                           f"{backbone['random_seed']}): not a usable metric")
    if validation and val_res is not None:
        prov["validation"] = {
            "method": "repeated scene-disjoint splits per dataset; the final weights above "
                      "are fitted on all scenes, these figures estimate their test performance",
            "train_ratios": list(train_ratios),
            # seeds of the sampled splits (enumerated splits have none), all ratios together
            "split_seeds": sorted({sp.seed for c in val_res.splits for sp in c.splits
                                   if sp.seed is not None}),
            "splits": [c.describe() for c in val_res.splits],
            "validation_ratio": val_ratio if config.select == "val" else None,
            "notes": val_res.notes + ([] if HONESTY_NOTE in val_res.notes else [HONESTY_NOTE]),
            "summary": val_res.summary.to_dict(orient="records"),
        }
    else:
        prov["validation"] = None
    return _jsonable(prov)


def _jsonable(obj: Any) -> Any:
    """Plain JSON values: numpy scalars unwrapped, NaN/inf as null (strict JSON has neither)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def prepare(specs: Sequence[DatasetSpec], source: FeatureSource, cache_root: str | Path, *,
            dmos_scale: str = "quality", include_references: bool = False,
            show_progress: bool = True) -> CalibrationData:
    """Load the datasets and their features (computing what the cache lacks)."""
    items = load_datasets(list(specs), dmos_scale=dmos_scale,
                          include_references=include_references)
    return build_data(items, source, cache_root, show_progress=show_progress)
