"""Reading study ratings (tidy CSV or session files) against the manifest.

Bad rows never stop the run: each one becomes an :class:`InputProblem` naming the file and row
(CSV line or session trial) and is left out. Only problems that leave nothing to analyse raise
:class:`AnalysisError`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from session_store.pull_listing import server_withdrawals
from stimuli_manifests import LoadedManifest, Manifest, StimuliError, load_manifest

from .csv_inputs import frame_from_csvs
from .data import Exclusion, InputProblem, PanelAnswers, RatingSet, rater_order
from .errors import AnalysisError
from .panel import panel_from_sessions
from .presentation_text import presentation
from .quality import facts_from_rows, facts_from_sessions
from .sessions import (
    SESSION_SUFFIXES,
    line_ending_twins,
    missing_from_pull,
    read_one,
    select_sessions,
    session_files,
)

log = logging.getLogger(__name__)

__all__ = ["SESSION_SUFFIXES", "load_ratings", "ratings_from_frame", "read_manifest"]

def read_manifest(path: str | Path) -> LoadedManifest:
    """Load the study manifest (structure only: the videos are not needed for analysis)."""
    try:
        return load_manifest(path)
    except StimuliError as exc:
        raise AnalysisError(f"cannot use manifest {path}: {exc}") from None


def _frame_from_sessions(
    paths: Sequence[str | Path], loaded: LoadedManifest, include_pilots: bool = False
) -> tuple[pd.DataFrame, list[InputProblem], list[Exclusion], pd.DataFrame, PanelAnswers]:
    records = []
    with session_files(paths) as (sources, problems):
        for source in tqdm(sources, desc="sessions", unit="file", leave=False,
                           disable=len(sources) < 20):
            try:
                records.append(read_one(source))
            except AnalysisError as exc:
                problems.append(InputProblem(source.origin, None,
                                             str(exc).removeprefix(f"{source.origin}: ")))
    problems += missing_from_pull(paths, records)
    selection = select_sessions(records, loaded.manifest.study_id, loaded.sha256,
                                include_pilots=include_pilots,
                                twins=line_ending_twins(loaded.source),
                                deleted=server_withdrawals(paths, loaded.manifest.study_id))
    for exc in selection.exclusions:
        log.warning("%s", exc)
    problems += selection.problems
    frames = []
    for rank, rec in enumerate(selection.used):
        frame = pd.DataFrame(rec.ratings)
        if frame.empty:
            continue
        frame["_source"] = rec.path
        frame["_row"] = frame["trial"]
        frame["_rank"] = rank
        frames.append(frame)
    if not frames:
        why = "; ".join(str(x) for x in [*selection.exclusions, *problems][:3])
        raise AnalysisError("no usable ratings in the session files: " + (why or "they are "
                                                                           "empty"))
    facts = facts_from_sessions(selection.used)
    problems += _simulated_among_real(facts)
    return (pd.concat(frames, ignore_index=True), problems, selection.exclusions, facts,
            panel_from_sessions(selection.used, loaded.manifest.panel))


def _simulated_among_real(facts: pd.DataFrame) -> list[InputProblem]:
    """Simulated sessions (``cgvq-study simulate``) mixed with real ones: named, because a
    dry run simulated into the folder real sessions are copied to would enter the DMOS."""
    if facts is None or "timing_mode" not in facts.columns:
        return []
    simulated = facts["timing_mode"].astype(str).str.contains("simulated")
    if not simulated.any() or simulated.all():
        return []
    sim = [str(r) for r in facts.index[simulated]]
    names = ", ".join(sim[:5]) + (f" and {len(sim) - 5} more" if len(sim) > 5 else "")
    return [InputProblem("<sessions>", None,
                         f"{int(simulated.sum())} simulated rater(s) ({names}) are mixed with "
                         f"{int((~simulated).sum())} from the player; simulated sessions are "
                         "not participant data: analyse them apart")]


def _cell_text(value: object) -> str:
    """A cell as plain text for a message: ``nan``, ``inf``, ``3.5``, ``'abc'``, ``(empty)``
    (never a numpy repr such as ``np.float64(nan)``)."""
    if isinstance(value, str):
        return repr(value) if value.strip() else "(empty)"
    try:
        return f"{float(value):g}"  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return repr(str(value))


def _problem(row: pd.Series, message: str) -> InputProblem:
    return InputProblem(str(row["_source"]), int(row["_row"]), message)


def ratings_from_frame(
    frame: pd.DataFrame,
    loaded: LoadedManifest,
    *,
    problems: Iterable[InputProblem] = (),
    source: str = "",
    exclusions: Iterable[Exclusion] = (),
    facts: pd.DataFrame | None = None,
) -> RatingSet:
    """Validate tidy rating rows against the manifest and build a :class:`RatingSet`.

    Rows with a missing or non-numeric rating, a rating outside the scale, an unknown stimulus,
    a reference that contradicts the manifest, or a repeated (participant, stimulus,
    repetition) are reported and left out. Of duplicates, the row of the earliest session
    (``_rank``; session files are ranked by start time) is kept, then the first in the file.
    Long on purpose: one pass of row checks over the same columns, each of which reports in
    the same problem list; split apart they would hand the frame and its masks back and forth.
    ``facts`` (per participant, from the session files) go into ``rater_info`` together with
    each participant's completeness.
    """
    manifest = loaded.manifest
    scale = manifest.scale
    problems = list(problems)
    if frame.empty:
        raise AnalysisError(f"the ratings table {source or '<ratings>'} has no rows (a header "
                            "only); give a table with at least one rating per row")
    if "_source" not in frame.columns:
        frame = frame.assign(_source=source or "<ratings>", _row=np.arange(len(frame)) + 2)
    if "_rank" not in frame.columns:
        frame = frame.assign(_rank=0)
    frame = frame.sort_values(["_rank"], kind="stable")
    stimuli = manifest.stimuli(include_hidden_references=True)
    by_id = {s.id: s for s in stimuli}

    values = pd.to_numeric(frame["rating"], errors="coerce").to_numpy(dtype=float)
    stim = frame["stimulus"].astype(str).to_numpy()
    part = frame["participant"].astype(object).where(frame["participant"].notna(), "") \
        .map(str).str.strip().to_numpy()
    no_part = np.isin(part, ["", "nan", "None", "<NA>"])
    not_num = ~np.isfinite(values)
    with np.errstate(invalid="ignore"):
        outside = ~not_num & ((values < scale.min) | (values > scale.max))
    unknown = ~np.isin(stim, list(by_id))
    expected_ref = np.array([by_id[s].reference if s in by_id else "" for s in stim], dtype=object)
    if "reference" in frame.columns:
        refs = frame["reference"].astype(str).to_numpy()
        wrong_ref = ~unknown & ~np.isin(refs, ["", "nan", "<NA>"]) & (refs != expected_ref)
    else:
        refs = expected_ref
        wrong_ref = np.zeros(len(frame), dtype=bool)
    keep = np.ones(len(frame), dtype=bool)
    checks = (
        (no_part, lambda i: "no participant id; row left out"),
        (not_num, lambda i: f"rating {_cell_text(frame['rating'].iloc[i])} is missing or not a "
         "number; row left out"),
        (outside, lambda i: f"rating {values[i]:g} is outside the scale "
         f"[{scale.min:g}, {scale.max:g}]; row left out"),
        (unknown, lambda i: f"stimulus {stim[i]!r} is not in the manifest; row left out"),
        (wrong_ref, lambda i: f"reference {refs[i]!r} contradicts the manifest "
         f"({expected_ref[i]!r} for {stim[i]}); row left out"),
    )
    for mask, message in checks:
        for i in np.flatnonzero(mask & keep):
            problems.append(_problem(frame.iloc[i], message(i)))
        keep &= ~mask

    if "repetition" in frame.columns:
        rep = pd.to_numeric(frame["repetition"], errors="coerce")
    else:
        rep = pd.Series(np.nan, index=frame.index)
    for i in np.flatnonzero(keep & rep.isna().to_numpy() & ("repetition" in frame.columns)):
        problems.append(_problem(frame.iloc[i], "repetition is missing or not a number; "
                                 "row left out"))
        keep[i] = False
    if "repetition" not in frame.columns:
        # Number repetitions by order of appearance when the column is absent.
        rep = frame.groupby(["participant", "stimulus"]).cumcount().astype(float)
    good = frame.loc[keep].assign(_rating=values[keep], _rep=rep[keep].to_numpy(),
                                  participant=part[keep], stimulus=stim[keep])
    key = ["participant", "stimulus", "_rep"]
    dup = good.duplicated(key, keep="first")
    first = good.loc[~dup].set_index(key)[["_source", "_row", "_rank"]]
    for _, row in good.loc[dup].iterrows():
        kept = first.loc[(row["participant"], row["stimulus"], row["_rep"])]
        if kept["_rank"] != row["_rank"]:
            where = f"the rating from the earlier session ({kept['_source']}) is used"
        else:
            where = f"the row read first ({kept['_source']}, row {kept['_row']}) is used"
        problems.append(_problem(row, f"duplicate rating of {row['stimulus']} repetition "
                                 f"{row['_rep']:g} by {row['participant']}; {where} "
                                 "(this row left out)"))
    good = good.loc[~dup]
    if good.empty:
        first = "; ".join(str(p) for p in problems[:3])
        raise AnalysisError("no valid ratings left after checking the input against the "
                            "manifest" + (f" (first problems: {first})" if first else ""))

    rated = set(good["stimulus"])
    order = [s for s in stimuli if s.id in rated]
    unrated = [s.id for s in stimuli if s.id not in rated
               and (not s.is_hidden_reference or manifest.protocol.hidden_reference)]
    if unrated:
        problems.append(InputProblem(source or "<ratings>", None,
                                     f"{len(unrated)} manifest stimulus/stimuli never rated "
                                     f"(e.g. {', '.join(unrated[:5])})"))
    raters = rater_order(good["participant"])
    # Repetition slot: rank of the repetition value within (rater, stimulus).
    good = good.sort_values(["participant", "stimulus", "_rep"])
    slot = good.groupby(["participant", "stimulus"]).cumcount().to_numpy()
    e_idx = pd.Index([s.id for s in order]).get_indexer(good["stimulus"])
    s_idx = pd.Index(raters).get_indexer(good["participant"])
    ratings = good["_rating"].to_numpy(dtype=float)
    if scale.direction == "lower_is_better":
        ratings = scale.min + scale.max - ratings
        log.info("scale is lower-is-better: ratings are mirrored so that higher is better")
    scores = np.full((len(order), len(raters), int(slot.max()) + 1), np.nan)
    scores[e_idx, s_idx, slot] = ratings

    policy, settings = allocation_of(manifest)
    # Without session files a plan is the manifest's: its stimuli that anybody rated (one
    # nobody rated is a problem of its own, not a gap in every rater's session).
    n_planned_stimuli = len(manifest.stimuli(include_hidden_references=manifest.protocol
                                             .hidden_reference)) - len(unrated)
    repetitions = manifest.protocol.repetitions
    if facts is None and scores.shape[2] < repetitions:
        problems.append(InputProblem(
            source or "<ratings>", None,
            f"no rater rated a stimulus more than {scores.shape[2]} time(s), but the "
            f"manifest's protocol.repetitions is {repetitions} (3 when not given), so every "
            f"rater's plan counts {repetitions} ratings per stimulus: if each stimulus was "
            f"rated {scores.shape[2]} time(s), set protocol.repetitions to {scores.shape[2]}"))
    planned = n_planned_stimuli * repetitions
    if facts is None and policy != "adaptive":
        planned = _planned_by_design(scores, repetitions) or planned
    info = _rater_info(good, raters, frame.loc[~no_part], facts, planned=planned,
                       stimuli=n_planned_stimuli if policy == "adaptive" else None)
    table = pd.DataFrame(
        {
            "reference": [s.reference for s in order],
            "scene": [s.scene for s in order],
            "method": [s.method for s in order],
            "level": pd.array([s.level for s in order], dtype="Int64"),
            "is_hidden_reference": [s.is_hidden_reference for s in order],
        },
        index=pd.Index([s.id for s in order], name="stimulus"),
    )
    return RatingSet(
        stimuli=table, raters=raters, scores=scores, scale_min=float(scale.min),
        scale_max=float(scale.max), ref_score=float(scale.max), study=manifest.study_id,
        source=source, problems=problems, exclusions=list(exclusions), rater_info=info,
        allocation=policy, allocation_settings=settings, scale_direction=scale.direction,
        scale_labels=tuple((float(lb.position), lb.text) for lb in scale.labels),
        scale_question=scale.shown_question,
        presentation=presentation(manifest),
    )


NARROW_SCALE_SHARE = 0.1
"""Ratings spread over less of the manifest's scale than this look like another scale's."""


def _check_scale(loaded: LoadedManifest, rs: RatingSet) -> None:
    """Refuse a ratings CSV plainly on another scale than the manifest's default one (ACR
    1..5 read on 0..100 gives DMOS of 96 to 100 and no error): whole numbers spread over a
    tenth of the scale at most and none above 10 (the small ACR, DCR and 0..10 scales), from
    a manifest that does not give its scale. Session files need no such check: the player's
    slider wrote them on the manifest's scale."""
    manifest = loaded.manifest
    scale = manifest.scale
    ratings = rs.scores[np.isfinite(rs.scores)]
    if "scale" in manifest.model_fields_set or ratings.size < 2:
        return
    low, high = float(ratings.min()), float(ratings.max())
    whole = bool(np.all(ratings == np.round(ratings)))
    if whole and high <= 10 and high - low <= NARROW_SCALE_SHARE * (scale.max - scale.min):
        raise AnalysisError(
            f"every rating is a whole number from {low:g} to {high:g}, but the manifest "
            f"{loaded.source or ''} gives no scale, so {scale.min:g}..{scale.max:g} is taken: add "
            f'"scale": {{"min": ..., "max": ..., "labels": []}} with the scale the ratings '
            "were given on")


def allocation_of(manifest: Manifest) -> tuple[str, dict[str, Any] | None]:
    """The manifest's allocation policy and, for ``adaptive``, its settings (defaults filled
    in), so the report can say how the ratings were allocated."""
    settings = manifest.protocol.adaptive_settings()
    return manifest.protocol.allocation, (settings.model_dump() if settings else None)


def _planned_by_design(scores: np.ndarray, repetitions: int) -> int | None:
    """The trials of a design that repeats some stimuli less often than
    ``protocol.repetitions`` (hidden references once, conditions three times): when most
    raters (at least half, and two) gave every stimulus the same number of ratings, with the
    manifest's count for some and fewer for others, that pattern is the plan, and none of
    them is partial for following it. None when the ratings show no such shared pattern."""
    counts = np.isfinite(scores).sum(axis=2).T  # (raters, stimuli)
    if counts.shape[0] < 2:
        return None
    patterns, freq = np.unique(counts, axis=0, return_counts=True)
    mode = patterns[int(np.argmax(freq))]
    if freq.max() < max(2, counts.shape[0] / 2) or mode.max() != repetitions or \
            mode.min() < 1 or mode.min() == repetitions:
        return None
    return int(mode.sum())


def _rater_info(good: pd.DataFrame, raters: list[str], frame: pd.DataFrame,
                facts: pd.DataFrame | None, planned: int,
                stimuli: int | None = None) -> pd.DataFrame:
    """Per participant: valid ratings, planned trials, completeness, and the session facts.

    ``stimuli`` (adaptive designs): without session files the plan of each participant is
    unknown (the server chose their later blocks), so completeness is the share of the
    ``stimuli`` they rated at least once, and ``n_planned`` stays empty.
    """
    info = facts.copy() if facts is not None and not facts.empty else \
        facts_from_rows(frame.assign(participant=frame["participant"].astype(str)))
    info = info.reindex(list(dict.fromkeys([*raters, *info.index])))
    n = good.groupby("participant").size()
    info["n_ratings"] = [int(n.get(r, 0)) for r in info.index]
    known = "n_planned" in info.columns and info["n_planned"].notna().any()
    if stimuli is not None and not known:
        seen = good.groupby("participant")["stimulus"].nunique()
        info["n_planned"] = np.nan
        info["completeness"] = [min(1.0, int(seen.get(r, 0)) / max(stimuli, 1))
                                for r in info.index]
    else:
        if not known:
            info["n_planned"] = planned
        info["n_planned"] = info["n_planned"].fillna(planned)
        with np.errstate(invalid="ignore", divide="ignore"):
            info["completeness"] = np.minimum(
                1.0, info["n_ratings"] / info["n_planned"].where(info["n_planned"] > 0))
    info["status"] = ["used" if r in raters else "no valid ratings" for r in info.index]
    info.index.name = "rater"
    return info


def load_ratings(
    manifest: str | Path,
    *,
    ratings_csv: str | Path | Sequence[str | Path] | None = None,
    sessions: Sequence[str | Path] | None = None,
    include_pilots: bool = False,
) -> RatingSet:
    """Ratings of a study from the tidy CSV(s) or session files, checked against the manifest
    (``include_pilots``: keep paced pilot sessions beside participants' ones)."""
    loaded = read_manifest(manifest)
    if (ratings_csv is None) == (sessions is None):
        raise AnalysisError("give the ratings either as a CSV (--ratings) or as session "
                            "files (--sessions), not both or neither")
    problems: list[InputProblem] = []
    exclusions: list[Exclusion] = []
    facts = None
    panel = None
    if ratings_csv is not None:
        paths = [ratings_csv] if isinstance(ratings_csv, (str, Path)) else list(ratings_csv)
        frame, exclusions = frame_from_csvs(
            [Path(p) for p in paths], loaded.manifest.study_id, loaded.sha256,
            deleted=server_withdrawals(paths, loaded.manifest.study_id))
        for exc in exclusions:
            log.warning("%s", exc)
        source = ", ".join(str(p) for p in paths)
    else:
        frame, problems, exclusions, facts, panel = _frame_from_sessions(
            sessions or [], loaded, include_pilots)
        source = ", ".join(str(p) for p in sessions or [])
    rs = ratings_from_frame(frame, loaded, problems=problems, source=source,
                            exclusions=exclusions, facts=facts)
    if ratings_csv is not None:
        _check_scale(loaded, rs)
    rs.panel = panel
    for prob in rs.problems:
        log.warning("input problem: %s", prob)
    return rs
