"""Honest validation: fit on some scenes, measure on the others, repeat with seeds.

For each train ratio, the scenes of every dataset are split (no scene on both sides) in
distinct ways (:func:`~.splits.distinct_splits`: all possible splits when there are no more
than the repeats asked for, else seeds drawn without repeating a split), omega/alpha are
fitted on the training videos (the step kept is chosen by training or validation loss, or
is the last one, never by test results) and the metric's agreement with the human scores
is measured on training, validation and test videos, per dataset: PLCC, SRCC, KRCC of
q = 100 - alpha * pooled error, and the RMSE on the 0..100 scale after the scale anchoring
fitted on the training videos. Uniform omega is measured on the same test videos as a
baseline. All splits of one ratio are fitted together in one vectorised loop. Means and
intervals are over these distinct splits.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..errors import CGVQMError
from ..scale_anchor import apply_anchor
from .anchoring import fit_anchor, refit_alpha
from .fitting import FitConfig, fit, pooled_errors
from .splits import SplitSet, distinct_splits
from .stats import correlations, interval

log = logging.getLogger(__name__)

SELECTION_NOTE = {
    "train": "weights kept at the step with the lowest training loss (as upstream)",
    "val": "weights kept at the step with the lowest loss on held-out validation scenes",
    "last": "weights of the last step kept (fixed step count)",
}
HONESTY_NOTE = "test scenes were never used to fit, select or anchor anything"


@dataclass
class CalibrationData:
    """Everything the fit needs, aligned by video."""

    items: pd.DataFrame  # dataset, stimulus, scene, target, ... one row per video
    M: np.ndarray  # (V, P, N) float32 per-patch channel MSD, zero-padded
    counts: np.ndarray  # (V,) patches per video

    @property
    def y(self) -> np.ndarray:
        return self.items["target"].to_numpy(dtype=np.float64)

    @property
    def dataset_names(self) -> list[str]:
        return list(dict.fromkeys(self.items["dataset"]))

    @property
    def groups(self) -> np.ndarray:
        names = self.dataset_names
        return self.items["dataset"].map({n: i for i, n in enumerate(names)}).to_numpy()


@dataclass
class ValidationResult:
    per_split: pd.DataFrame  # one row per (ratio, split, model, subset, dataset)
    summary: pd.DataFrame  # mean and intervals over the distinct splits
    notes: list[str]
    splits: list[SplitSet] = field(default_factory=list)  # per train ratio


def _measure(data: CalibrationData, q: np.ndarray, masks: dict[str, np.ndarray],
             anchored: np.ndarray | None, base: dict) -> list[dict]:
    rows = []
    y = data.y
    for subset, mask in masks.items():
        for d in data.dataset_names:
            sel = mask & (data.items["dataset"].to_numpy() == d)
            if not sel.any():
                continue
            c = correlations(q[sel], y[sel])
            rmse = float(np.sqrt(np.mean((anchored[sel] - y[sel]) ** 2))) \
                if anchored is not None else np.nan
            rows.append({**base, "subset": subset, "dataset": d, "n_videos": int(sel.sum()),
                         "n_scenes": int(data.items.loc[sel, "scene"].nunique()),
                         "plcc": c["plcc"], "srcc": c["srcc"], "krcc": c["krcc"],
                         "rmse_anchored": rmse})
    return rows


def validate(data: CalibrationData, train_ratios: Sequence[float], seeds: Sequence[int],
             config: FitConfig, *, val_ratio: float = 0.25, anchor: str = "logistic",
             dmos_scale: str = "quality") -> ValidationResult:
    """Repeated scene-disjoint splits for every train ratio; see the module docstring."""
    scenes = data.items["scene"].astype(str).tolist()
    dsets = data.items["dataset"].astype(str).tolist()
    rows: list[dict] = []
    n_ch = data.M.shape[2]
    uniform = np.full(n_ch, 1.0 / n_ch)
    E_uniform = pooled_errors(data.M, data.counts, uniform, config.pooling)
    split_sets: list[SplitSet] = []
    for ratio in train_ratios:
        chosen = distinct_splits(scenes, dsets, ratio, seeds,
                                 val_ratio=val_ratio if config.select == "val" else 0.0)
        split_sets.append(chosen)
        splits = chosen.splits
        train = np.stack([s.train for s in splits])
        val = np.stack([s.val for s in splits]) if config.select == "val" else None
        log.info("train ratio %.2f: fitting %d splits", ratio, len(splits))
        res = fit(data.M, data.counts, data.y, data.groups, train, val=val, config=config)
        E = pooled_errors(data.M, data.counts, res.omega, config.pooling)
        for r, split in enumerate(splits):
            masks = {"train": split.train, "val": split.val, "test": split.test}
            q = 100.0 - res.alpha[r] * E[r]
            fit_set = split.train | split.val
            anchored = _anchored(E[r], data.y, fit_set, anchor, config.pooling)
            base = {"train_ratio": ratio, "split": r, "seed": split.seed, "model": "fitted",
                    "best_step": int(res.best_step[r])}
            rows += _measure(data, q, masks, anchored, base)
            # the baseline: uniform omega, its scale anchored on the same training videos
            qu = 100.0 - E_uniform
            anchored_u = _anchored(E_uniform, data.y, fit_set, anchor, config.pooling)
            rows += _measure(data, qu, {"test": split.test}, anchored_u,
                             {**base, "model": "uniform", "best_step": 0})
    per_split = pd.DataFrame(rows)
    per_split["seed"] = per_split["seed"].astype("Int64")  # empty for enumerated splits
    summary = summarise(per_split)
    notes = [SELECTION_NOTE[config.select], HONESTY_NOTE]
    notes += [n for c in split_sets if (n := c.note(len(seeds))) is not None]
    signs = sign_notes(per_split, config.objective, dmos_scale)
    for note in signs:
        log.warning(note)
    return ValidationResult(per_split, summary, notes + signs, split_sets)


def wrong_scale_note(dmos_scale: str) -> str:
    """What a negative correlation in most fits says about ``--dmos-scale``: the other one
    is probably right (this toolkit's own DMOS is on the quality scale, larger = better)."""
    if dmos_scale == "impairment":
        return ("the DMOS is probably on a quality scale (larger = better, as this toolkit's "
                "DMOS), not an impairment one: rerun with --dmos-scale quality (the default)")
    return ("the DMOS is probably on an impairment scale (larger = worse); rerun with "
            "--dmos-scale impairment")


def sign_notes(per_split: pd.DataFrame, objective: str, dmos_scale: str = "quality"
               ) -> list[str]:
    """Warnings when fitted scores fall as human quality rises (on the training videos)."""
    tr = per_split[(per_split["model"] == "fitted") & (per_split["subset"] == "train")]
    plcc = tr["plcc"].to_numpy(dtype=float)
    plcc = plcc[np.isfinite(plcc)]
    if not plcc.size or (plcc >= 0).all():
        return []
    if np.mean(plcc) < 0 and (plcc < 0).mean() > 0.5:
        return ["the fitted scores correlate NEGATIVELY with the human scores in most splits: "
                + wrong_scale_note(dmos_scale)]
    hint = (" (the |PLCC| objective is blind to the sign: --objective plcc-signed fits only "
            "the right direction)" if objective == "plcc" else "")
    return [f"in {(plcc < 0).sum()} of {plcc.size} splits the fitted scores correlate "
            f"NEGATIVELY with the human scores on the training videos{hint}"]


def _anchored(E: np.ndarray, y: np.ndarray, fit_set: np.ndarray, method: str,
              pool: str) -> np.ndarray | None:
    if method == "none":
        return None
    try:
        alpha = refit_alpha(E[fit_set], y[fit_set])
        q = 100.0 - alpha * E
        return apply_anchor(fit_anchor(q[fit_set], y[fit_set], method, pool=pool), q)
    except CGVQMError as exc:
        log.warning("scale anchoring failed on one split (%s)", exc)
        return None


def summarise(per_split: pd.DataFrame) -> pd.DataFrame:
    """Mean, t-based 95% interval of the mean and 2.5-97.5% range over the splits (each
    distinct, see :func:`validate`; ``n_splits`` counts them)."""
    out = []
    keys = ["train_ratio", "model", "subset", "dataset"]
    for key, grp in per_split.groupby(keys, sort=False):
        rec = dict(zip(keys, key, strict=True))
        rec["n_splits"] = int(grp["split"].nunique())
        rec["n_videos"] = float(grp["n_videos"].mean())
        for col in ("plcc", "srcc", "krcc", "rmse_anchored"):
            iv = interval(grp[col].to_numpy(), bounds=(-1.0, 1.0) if col != "rmse_anchored"
                          else (0.0, np.inf))
            rec[col] = iv["mean"]
            rec[f"{col}_ci95_low"] = iv["ci95_low"]
            rec[f"{col}_ci95_high"] = iv["ci95_high"]
            rec[f"{col}_p2.5"] = iv["p2.5"]
            rec[f"{col}_p97.5"] = iv["p97.5"]
        out.append(rec)
    return pd.DataFrame(out)


def format_summary(summary: pd.DataFrame) -> str:
    """A terminal table: one line per (ratio, model, subset, dataset)."""
    def cell(rec: pd.Series, col: str) -> str:
        m, lo, hi = rec[col], rec[f"{col}_ci95_low"], rec[f"{col}_ci95_high"]
        if not np.isfinite(m):
            return "     n/a          "
        if not np.isfinite(lo):
            return f"{m:6.3f}            "
        return f"{m:6.3f} [{lo:6.3f},{hi:6.3f}]"

    head = (f"{'ratio':>5} {'model':<7} {'subset':<6} {'dataset':<14} {'videos':>6}  "
            f"{'PLCC [95% CI]':<22}{'SRCC [95% CI]':<22}{'KRCC [95% CI]':<22} RMSE(0..100)")
    lines = [head, "-" * len(head)]
    for _, rec in summary.iterrows():
        rmse = rec["rmse_anchored"]
        lines.append(
            f"{rec['train_ratio']:>5.2f} {rec['model']:<7} {rec['subset']:<6} "
            f"{str(rec['dataset'])[:14]:<14} {rec['n_videos']:>6.0f}  {cell(rec, 'plcc'):<22}"
            f"{cell(rec, 'srcc'):<22}{cell(rec, 'krcc'):<22} "
            f"{'n/a' if not np.isfinite(rmse) else f'{rmse:.2f}'}")
    return "\n".join(lines)
