"""``p913`` (the default): screening not fooled by rater bias or by other bad raters.

The rule (the default):

1. **Correlation with the panel** (ITU-T P.913's subject screening, from the VQEG Multimedia
   test plan): for each rater, ``r1`` = Pearson r between their ratings (averaged over
   repetitions) and the panel's per-stimulus mean, and ``r2`` = Pearson r between their
   per-HRC means and the panel's per-HRC means (HRC = distortion method and level, the hidden
   reference its own HRC; only with at least 4 HRCs). The correlation test fails when
   ``r1 < 0.75`` and (``r2 < 0.8`` or no ``r2``). Two departures from P.913 make it robust:
   the panel mean leaves the rater out (a rater cannot vouch for themselves), and the rule is
   iterated: the worst failing rater is removed, the panel recomputed, and the test repeated,
   so several bad raters cannot hide each other (masking). Pearson r ignores a rater's offset
   and scale use, so a consistent rater with a bias is never at risk.
2. **Confirmed by the MLE inconsistency**: SUREAL's ITU-T P.910 subject model (MLE_CO_AP2,
   Li & Bampis 2020) estimates each rater's bias and inconsistency (noise s.d.) jointly with
   the quality scores. A rater's inconsistency is an outlier when its robust z-score
   ``0.6745 (v - median) / MAD`` exceeds 3.5 (Iglewicz & Hoaglin 1993); median and MAD are
   unaffected by up to half of the panel being bad. With fewer than 6 raters the spread cannot
   be estimated robustly and the correlation test decides alone.

A rater is removed only when both fail: low correlation alone can come from a small or
unusual set of stimuli (a partial session), high inconsistency alone from a rater who uses a
wider part of the scale; random, inverted and inattentive raters fail both. A rater who gave
one value to everything (no variance, so no correlation) is removed without the second test.
Every removal and every near-miss (one test failed, or within 0.05 of r1's or 1.0 of z's
threshold) is explained in the result table.
"""

from __future__ import annotations

import logging
import warnings

import numpy as np
import pandas as pd

from ..data import RatingSet
from ..quality import MIN_PANEL_STIMULI, loo_correlation
from ..subject_models import mos_and_t, plausible, rater_stats_from_means, run_sureal
from .result import OutlierResult, RemovedRater
from .rule import ScreeningRule

log = logging.getLogger(__name__)

R1_MIN = 0.75
R2_MIN = 0.8
Z_MAX = 3.5
MIN_HRCS = 4
MIN_RATERS_FOR_Z = 6
MIN_STIMULI = MIN_PANEL_STIMULI
"""r1 is the report's panel correlation, so it needs as many stimuli; fewer: no screening."""


def hrc_labels(rs: RatingSet) -> np.ndarray:
    """Per stimulus, its HRC: method and level (hidden references form one HRC)."""
    st = rs.stimuli
    return np.array(["reference" if ref else f"{m}|{lv}"
                     for m, lv, ref in zip(st["method"], st["level"],
                                           st["is_hidden_reference"], strict=True)])


def loo_hrc_correlation(means: np.ndarray, hrc: np.ndarray) -> np.ndarray:
    """Per rater, r2: Pearson r between the rater's per-HRC means and the other raters'."""
    labels = list(dict.fromkeys(hrc))
    n_raters = means.shape[1]
    if len(labels) < MIN_HRCS:
        return np.full(n_raters, np.nan)
    onehot = np.stack([hrc == h for h in labels])  # (H, E)
    finite = np.isfinite(means)
    x = np.where(finite, means, 0.0)
    sums, counts = onehot @ x, onehot @ finite.astype(float)  # (H, S)
    out = np.full(n_raters, np.nan)
    for s in range(n_raters):
        with np.errstate(invalid="ignore", divide="ignore"):
            own = sums[:, s] / counts[:, s]
            others = (sums.sum(axis=1) - sums[:, s]) / (counts.sum(axis=1) - counts[:, s])
        ok = np.isfinite(own) & np.isfinite(others)
        if ok.sum() >= MIN_HRCS and own[ok].std() > 0 and others[ok].std() > 0:
            out[s] = float(np.corrcoef(own[ok], others[ok])[0, 1])
    return out


def inconsistency(rs: RatingSet) -> tuple[np.ndarray, str]:
    """Per rater noise s.d. from SUREAL's P.910 model; a moment estimate if it fails."""
    from sureal.subjective_model import (
        MaximumLikelihoodEstimationModelContentObliviousAlternativeProjection2 as P910Model,
    )

    out = run_sureal(P910Model, rs)
    if plausible(out, rs):
        return np.asarray(out["observer_inconsistency"], dtype=float), "SUREAL MLE_CO_AP2"
    mos, _, _ = mos_and_t(rs.scores)
    _, _, v, _ = rater_stats_from_means(rs, mos)
    return v, "residual s.d. around the MOS after removing each rater's bias"


def robust_z(values: np.ndarray, floor: float) -> np.ndarray:
    """Iglewicz-Hoaglin modified z-score, with the MAD floored at ``floor``."""
    v = np.asarray(values, dtype=float)
    med = np.nanmedian(v)
    mad = max(float(np.nanmedian(np.abs(v - med))), floor)
    return 0.6745 * (v - med) / mad


def p913_screen(rs: RatingSet, *, r1_min: float = R1_MIN, r2_min: float = R2_MIN,
                z_max: float = Z_MAX) -> OutlierResult:
    """Iterated P.913 correlation screening confirmed by the MLE inconsistency (see module)."""
    means = rs.rater_means()
    hrc = hrc_labels(rs)
    kept = list(range(rs.n_raters))
    removed: list[RemovedRater] = []
    stats: dict[str, dict] = {}
    span = rs.scale_max - rs.scale_min
    source = ""
    while len(kept) >= 3:
        sub = rs.with_raters(kept)
        r1 = loo_correlation(means[:, kept], MIN_STIMULI)
        r2 = loo_hrc_correlation(means[:, kept], hrc)
        n_stim = np.isfinite(means[:, kept]).sum(axis=0)
        use_z = len(kept) >= MIN_RATERS_FOR_Z
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            v, source = inconsistency(sub)
            z = robust_z(v, 0.01 * span) if use_z else np.full(len(kept), np.nan)
        screened = n_stim >= MIN_STIMULI
        corr_fail = screened & ~(r1 >= r1_min) & ~(r2 >= r2_min)
        inc_fail = (z > z_max) if use_z else np.ones(len(kept), dtype=bool)
        # One value for everything discriminates nothing, whatever its residual spread.
        flat = screened & (np.nanmax(means[:, kept], axis=0) == np.nanmin(means[:, kept],
                                                                           axis=0))
        inc_fail = inc_fail | flat
        for j, k in enumerate(kept):
            stats[rs.raters[k]] = {
                "r1": r1[j], "r2": r2[j], "inconsistency": v[j], "inconsistency_z": z[j],
                "n_stimuli": int(n_stim[j]), "n_raters": len(kept),
                "corr_fail": bool(corr_fail[j]), "inc_fail": bool(inc_fail[j] and use_z),
            }
        both = np.flatnonzero(corr_fail & inc_fail)
        if both.size == 0:
            break
        # The worst first: lowest r1 (no variance counts as lowest), then highest z.
        key = np.where(np.isfinite(r1[both]), r1[both], -2.0)
        j = int(both[np.lexsort((-np.nan_to_num(z[both], nan=0.0), key))[0]])
        who = kept.pop(j)
        name = rs.raters[who]
        st = stats[name]
        reason = _removal_reason(st, r1_min, r2_min, z_max, use_z)
        removed.append(RemovedRater(rater=name, method="p913", statistic_name="r1",
                                    statistic=float(r1[j]), critical=r1_min,
                                    second_name="inconsistency_z", second=float(z[j]),
                                    second_critical=z_max if use_z else float("nan"),
                                    reason=reason))
        stats[name]["decision"] = "removed"
        stats[name]["reason"] = reason
        log.info("P.913 screening: removed rater %s (%s)", name, reason)
    for k in kept:
        st = stats.get(rs.raters[k])
        if st is None:
            continue
        st["decision"] = "kept"
        st["reason"] = _kept_reason(st, r1_min, r2_min, z_max)
    table = pd.DataFrame.from_dict(stats, orient="index").rename_axis("rater")
    table = table.reindex(rs.raters)
    table = table.drop(columns=["corr_fail", "inc_fail"], errors="ignore")
    result = OutlierResult("p913", removed, kept,
                           {r: float(s["r1"]) for r, s in stats.items()}, table=table)
    result.notes.append(f"inconsistency from {source}" if source else "")
    return result


def _fmt(x: float, spec: str = ".2f") -> str:
    return "n/a" if x is None or not np.isfinite(x) else format(x, spec)


def _removal_reason(st: dict, r1_min: float, r2_min: float, z_max: float,
                    use_z: bool) -> str:
    if not np.isfinite(st["r1"]):
        return (f"one value for every stimulus (no variance in {st['n_stimuli']} stimuli): "
                "nothing to correlate, no information")
    r1 = f"r1 = {st['r1']:.2f} < {r1_min}"
    r2 = f"r2 = {_fmt(st['r2'])}" + (f" < {r2_min}" if np.isfinite(st["r2"]) else
                                     " (fewer than 4 HRCs)")
    inc = (f"inconsistency {st['inconsistency']:.3g} is an outlier (robust z = "
           f"{st['inconsistency_z']:.1f} > {z_max})") if use_z else \
        f"too few raters ({st['n_raters']}) for the inconsistency check: correlation decides"
    return (f"ratings do not follow the others ({r1}, {r2} against the leave-one-out panel "
            f"of {st['n_raters'] - 1} other raters); {inc}")


def _kept_reason(st: dict, r1_min: float, r2_min: float, z_max: float) -> str:
    r1, r2, z = st["r1"], st["r2"], st["inconsistency_z"]
    if st["n_stimuli"] < MIN_STIMULI:
        return f"not screened: only {st['n_stimuli']} stimuli rated"
    if st["corr_fail"]:
        return (f"near-miss, kept: r1 = {_fmt(r1)} < {r1_min} and r2 = {_fmt(r2)}, but the "
                f"inconsistency is ordinary (z = {_fmt(z, '.1f')} <= {z_max}): low agreement "
                "without excess noise")
    if st["inc_fail"]:
        return (f"near-miss, kept: inconsistency z = {_fmt(z, '.1f')} > {z_max}, but r1 = "
                f"{_fmt(r1)} (r2 = {_fmt(r2)}) follows the panel: noisier than the others, "
                "given less weight by the MLE")
    near = []
    if np.isfinite(r1) and r1 < r1_min + 0.05:
        near.append(f"r1 = {r1:.2f} within 0.05 of {r1_min}")
    if np.isfinite(z) and z > z_max - 1.0:
        near.append(f"z = {z:.1f} within 1 of {z_max}")
    if near:
        return "near-miss, kept: " + "; ".join(near)
    return ""


RULE = ScreeningRule(
    name="p913", order=0,
    summary=("ITU-T P.913 correlation with the leave-one-out panel, iterated, confirmed by the "
             "MLE inconsistency"),
    screen=p913_screen, min_raters=3)
