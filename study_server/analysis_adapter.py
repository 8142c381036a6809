"""The one place the server calls the ``analysis`` package (live statistics on the dashboard).

Imported only by the statistics worker of the server process, never by the participant's
side. Everything the dashboard needs from the analysis comes through :func:`analyse`, so a
change of the analysis API is absorbed here.
"""

from __future__ import annotations

import contextlib
import json
import logging
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from stimuli_manifests import LoadedManifest, parse_manifest

log = logging.getLogger(__name__)

SPLITS = 200
"""Random half splits for the live ceiling (the report uses more)."""
CI_DRAWS = 20


@dataclass
class StudyFigures:
    """What the analysis says about the ratings that arrived so far."""

    n_raters: int = 0
    """Raters behind the statistics (after the completeness rule and the screening)."""
    n_ratings: int = 0
    """Ratings behind the statistics (of those raters)."""
    n_partial: int = 0
    """Raters left out for now: below half of their trials, as the report would leave them."""
    partial: list[str] = field(default_factory=list)
    """Their ids."""
    icc2k: float | None = None
    icc2k_ci: tuple[float, float] | None = None
    split_half_plcc: float | None = None
    split_half_sb: float | None = None
    ceiling_bound: float | None = None  # sqrt of split_half_sb: a perfect metric's PLCC
    split_half_range: tuple[float, float] | None = None
    """The 95 % range of the split-half PLCC over the random splits."""
    removed: list[str] = field(default_factory=list)
    """Raters the screening would remove (with the reason)."""
    removed_reasons: dict[str, str] = field(default_factory=dict)
    dmos: pd.DataFrame | None = None
    model: str | None = None
    figures: dict[str, bytes] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)


@contextlib.contextmanager
def _analysis_quiet() -> Iterator[None]:
    """The analysis logs its decisions (a rater screened out) at INFO, once per report; the
    server reruns it every few seconds, and the same lines filled its log. Warnings pass."""
    logger = logging.getLogger("analysis")
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(level)


def loaded_manifest(manifest_bytes: bytes, sha256: str) -> LoadedManifest:
    manifest = parse_manifest(json.loads(manifest_bytes), source="manifest")
    return LoadedManifest(manifest, None, Path("."), sha256)


def analyse(frame: pd.DataFrame, loaded: LoadedManifest, *, seed: int = 0,
            figure: bool = True) -> StudyFigures:
    """Screening, ICC(2,k), split-half ceiling and DMOS per scene with CIs, from tidy rows
    (the ratings-table columns) of every session so far."""
    from analysis import AnalysisConfig, AnalysisError, ratings_from_frame, run_analysis

    out = StudyFigures()
    try:
        rs = ratings_from_frame(frame, loaded, source="server")
    except AnalysisError as exc:
        out.problems.append(str(exc))
        return out
    out.n_raters = rs.n_raters
    if rs.n_raters < 3:
        out.problems.append(f"{rs.n_raters} rater(s) so far: the statistics start at 3")
        return out
    config = AnalysisConfig(seed=seed, n_splits=SPLITS, ci_draws=CI_DRAWS, n_boot=100)
    try:
        with _analysis_quiet():
            a = run_analysis(rs, config, progress=False)
    except AnalysisError as exc:
        out.problems.append(_live(str(exc), config.min_completeness))
        return out
    out.n_raters, out.n_ratings = a.screened.n_raters, a.screened.n_ratings
    out.partial = [e.who for e in a.screened.exclusions if e.kind == "partial rater"]
    out.n_partial = len(out.partial)
    out.removed = list(a.outliers.removed_names)
    out.removed_reasons = {r.rater: r.reason for r in a.outliers.removed}
    if a.reliability is not None:
        out.icc2k = float(a.reliability.icc["ICC(2,k)"])
        lo, hi = a.reliability.icc_ci["ICC(2,k)"]
        out.icc2k_ci = (float(lo), float(hi))
    if a.ceiling is not None:
        s = a.ceiling.summary()
        out.split_half_plcc = float(s["plcc"]["median"])
        out.split_half_sb = float(s["plcc_spearman_brown"]["median"])
        out.ceiling_bound = float(s["plcc_full_panel_bound"]["median"])
        out.split_half_range = (float(s["plcc"]["p2_5"]), float(s["plcc"]["p97_5"]))
    out.dmos = a.dmos()
    out.model = a.scores.model_name
    # A young study has unrated stimuli and no second repetition yet: not problems here.
    out.problems += [str(p) for p in a.problems
                     if "never rated" not in str(p) and "protocol.repetitions" not in str(p)]
    if figure:
        try:
            out.figures["dmos"] = _dmos_png(a)
        except Exception as exc:  # a figure is never worth losing the numbers for
            log.warning("DMOS figure failed: %s", exc)
    return out


def _live(message: str, min_completeness: float) -> str:
    """An analysis refusal in the words of a live view, which has no command-line options:
    too few raters past the completeness rule only means the study is young."""
    if "--min-completeness" in message:
        return (f"the statistics use the raters who have answered at least "
                f"{min_completeness:.0%} of their trials, as the report will; fewer than 2 "
                "have so far")
    return message


def _dmos_png(a: Any) -> bytes:
    from analysis.figures import dmos_per_scene, literal_text

    with tempfile.TemporaryDirectory() as tmp, literal_text():
        path = Path(tmp) / "dmos.png"
        dmos_per_scene(a, path)
        return path.read_bytes()


def panel_correlation(frame: pd.DataFrame, loaded: LoadedManifest) -> dict[str, float]:
    """Per participant, the report's leave-one-out panel correlation
    (:func:`analysis.quality.panel_correlation`) over the ratings so far; participants with
    too few stimuli for it are left out."""
    from analysis import AnalysisError, ratings_from_frame
    from analysis.quality import panel_correlation as panel_r

    if frame.empty:
        return {}
    try:
        rs = ratings_from_frame(frame, loaded, source="server")
    except AnalysisError:
        return {}
    return {str(p): float(r) for p, r in panel_r(rs).items() if np.isfinite(r)}


def allocation_fit_of(frame: pd.DataFrame, loaded: LoadedManifest, *, n_boot: int,
                      seed: int) -> dict[str, Any]:
    """The analysis' fit of the ratings so far as adaptive allocation needs it
    (:func:`analysis.allocation.allocation_fit`), as plain JSON data for the log."""
    from analysis import ratings_from_frame
    from analysis.allocation import allocation_fit

    rs = ratings_from_frame(frame, loaded, source="server")
    fit = allocation_fit(rs, n_boot=n_boot, seed=seed)
    cond = fit.condition_mask()
    return {"stimuli": fit.stimulus_ids, "halfwidth": fit.halfwidth.tolist(),
            "own_share": fit.own_share.tolist(), "reference": fit.reference.tolist(),
            "hidden": fit.hidden.tolist(), "ratings": fit.ratings.tolist(),
            "raters": rs.n_raters, "n_ratings": rs.n_ratings,
            "mean_width": float(2 * fit.halfwidth[cond].mean()) if cond.any() else None,
            "max_width": float(2 * fit.halfwidth[cond].max()) if cond.any() else None}


def plan_counts(fit: dict[str, Any], size: int, pending: dict[str, int],
                max_per_block: int, last: str | None = None) -> dict[str, int]:
    """How often each stimulus appears in the next block (:func:`analysis.allocation.plan_block`)
    from a logged fit and the ratings pending since it."""
    from analysis.allocation import AllocationFit, plan_block

    ids = list(fit["stimuli"])
    af = AllocationFit(ids, np.asarray(fit["halfwidth"], dtype=float),
                       np.asarray(fit["own_share"], dtype=float),
                       np.asarray(fit["reference"], dtype=int),
                       np.asarray(fit["hidden"], dtype=bool),
                       np.asarray(fit["ratings"], dtype=float))
    counts = plan_block(af, size, pending=np.array([pending.get(s, 0) for s in ids], dtype=float),
                        max_per_block=max_per_block,
                        last=ids.index(last) if last in ids else None)
    return {s: int(c) for s, c in zip(ids, counts, strict=True) if c}


def warm_up() -> None:
    """Import what the allocation uses (SUREAL, SciPy...), so the first request does not."""
    import analysis.allocation
    import analysis.scores  # noqa: F401
