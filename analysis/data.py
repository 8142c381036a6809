"""The in-memory rating set every analysis step works on.

Ratings become one array ``scores[stimulus, rater, repetition]`` (NaN for gaps), the layout
SUREAL uses, plus a table describing the stimuli (reference, scene, method, level, hidden
reference). Input problems found while building it travel with it so the report can list them.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from .errors import AnalysisError

STIMULUS_COLUMNS = ("reference", "scene", "method", "level", "is_hidden_reference")

ALLOCATIONS = ("full", "adaptive", "unbalanced")
"""How the ratings were allocated: ``full`` (every rater rates every stimulus the same number
of times), ``adaptive`` (the manifest's ``protocol.allocation``: block 1 holds every stimulus
once, later blocks give some stimuli more ratings), ``unbalanced`` (no such policy declared,
but the raters who finished gave some stimuli more ratings than others)."""


def rater_order(ids: Iterable[Any]) -> list[str]:
    """Participant ids as text, in the order a reader expects: numbers inside an id compare
    as numbers (P2 before P10, 9 before 10), so tables, figures and the rater axis of the
    rating array follow it; ties (P1, P01) fall back to the text."""

    def key(rater: str) -> tuple[tuple[tuple[int, int | str], ...], str]:
        parts = re.split(r"(\d+)", rater.casefold())
        return tuple((0, int(p)) if p.isdigit() else (1, p) for p in parts if p), rater

    return sorted({str(i) for i in ids}, key=key)


@dataclass(frozen=True)
class Exclusion:
    """Something left out of the analysis as a whole (a session, a rater), with the rule.

    ``kind`` is one of ``refused session``, ``duplicate session``, ``pilot session``,
    ``partial rater``, ``altered session`` (a partial rater whose file was changed outside the app),
    ``screened out``, ``rejected by the score model``, ``ended by vision check``,
    ``withdrawn participant`` (withdrawn on the server, no file left); ``who``
    names the file or rater, ``reason`` says why in words a reader of the report
    understands, ``rule`` names the rule and its threshold.
    """

    kind: str
    who: str
    reason: str
    rule: str = ""

    def __str__(self) -> str:
        return f"{self.kind}: {self.who}: {self.reason}"


@dataclass
class PanelAnswers:
    """Per participant: the last answer to each questionnaire question (by question id), and
    each vision check's outcome (passed, failed, inconclusive). See :mod:`analysis.panel`."""

    answers: dict[str, dict[str, Any]] = field(default_factory=dict)
    screenings: dict[str, dict[str, str]] = field(default_factory=dict)
    definition: Any = None  # the manifest's panel block (stimuli_manifests.panel.Panel)

    def failed_vision(self) -> list[str]:
        """Participants with at least one failed vision check, sorted."""
        return rater_order(p for p, tests in self.screenings.items()
                           if "failed" in tests.values())


@dataclass(frozen=True)
class InputProblem:
    """One bad input row or file: where it is and what was wrong; the row is left out."""

    source: str
    row: int | None
    message: str

    def __str__(self) -> str:
        where = f":{self.row}" if self.row is not None else ""
        return f"{self.source}{where}: {self.message}"


@dataclass
class RatingSet:
    """Ratings of one study in SUREAL's layout, on a higher-is-better scale.

    ``stimuli`` is indexed by stimulus id in the order of ``scores``' first axis; hidden
    references have ``is_hidden_reference`` true and their id equals their reference id.
    ``ref_score`` is the score a hidden reference anchors to in DMOS (the scale maximum).
    """

    stimuli: pd.DataFrame
    raters: list[str]
    scores: np.ndarray
    scale_min: float
    scale_max: float
    ref_score: float
    study: str = "study"
    source: str = ""
    problems: list[InputProblem] = field(default_factory=list)
    exclusions: list[Exclusion] = field(default_factory=list)
    # One row per participant seen in the input (also those left out), indexed by rater id:
    # completeness, session and presentation facts, status. See :mod:`analysis.quality`.
    rater_info: pd.DataFrame | None = None
    # Questionnaire answers and vision checks from the session files (None from a CSV).
    panel: PanelAnswers | None = None
    # The allocation policy (ALLOCATIONS): from the manifest, or "unbalanced" when inferred
    # from the counts; the adaptive settings when the manifest gives them.
    allocation: str = "full"
    allocation_settings: dict[str, Any] | None = None
    # What part of the study's ratings this set holds (empty: all of them); see
    # :func:`balanced_subset`.
    subset: str = ""
    # The scale as the participants saw it: "lower_is_better" when their ratings were
    # mirrored (scale_min + scale_max - rating) on reading, and its (position, text) labels
    # on their own scale; empty where the input does not say (a CSV without a manifest).
    scale_direction: str = "higher_is_better"
    scale_labels: tuple[tuple[float, str], ...] = ()
    scale_question: str = ""  # the question above the slider; "" where the input does not say
    # How the player showed the stimuli (analysis.presentation_text.presentation); None
    # without a manifest (a SUREAL dataset)
    presentation: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        self.scores = np.asarray(self.scores, dtype=float)
        if self.scores.ndim != 3:
            raise ValueError("scores must have shape (stimuli, raters, repetitions)")
        if self.scores.shape[0] != len(self.stimuli) or self.scores.shape[1] != len(self.raters):
            raise ValueError("scores shape does not match the stimuli and raters")
        if self.allocation not in ALLOCATIONS:
            raise ValueError(f"allocation must be one of {ALLOCATIONS}, got {self.allocation!r}")
        if self.allocation == "full" and not self.subset and \
                uneven_counts(self.scores, self.completeness()):
            self.allocation = "unbalanced"

    # -- shape ------------------------------------------------------------------------
    @property
    def n_stimuli(self) -> int:
        return self.scores.shape[0]

    @property
    def n_raters(self) -> int:
        return self.scores.shape[1]

    @property
    def n_repetitions(self) -> int:
        return self.scores.shape[2]

    @property
    def n_ratings(self) -> int:
        return int(np.isfinite(self.scores).sum())

    @property
    def stimulus_ids(self) -> list[str]:
        return [str(s) for s in self.stimuli.index]

    @property
    def balanced(self) -> bool:
        """False when stimuli get different numbers of ratings by design (adaptive or
        inferred): then statistics that need a balanced matrix use :func:`balanced_subset`."""
        return self.allocation == "full"

    def ratings_per_stimulus(self) -> np.ndarray:
        """Per stimulus, the number of ratings (over raters and repetitions)."""
        return np.isfinite(self.scores).sum(axis=(1, 2))

    @property
    def hidden_reference_mask(self) -> np.ndarray:
        return self.stimuli["is_hidden_reference"].to_numpy(dtype=bool)

    def reference_index(self) -> np.ndarray:
        """For every stimulus, the row of its reference's hidden-reference stimulus (-1: none)."""
        ids = self.stimuli.index.tolist()
        hidden = {
            ref: ids.index(sid)
            for sid, ref, is_ref in zip(
                ids, self.stimuli["reference"], self.stimuli["is_hidden_reference"], strict=True
            )
            if is_ref
        }
        return np.array([hidden.get(ref, -1) for ref in self.stimuli["reference"]], dtype=int)

    def rater_means(self) -> np.ndarray:
        """Ratings averaged over repetitions: (stimuli, raters), NaN where never rated."""
        counts = np.isfinite(self.scores).sum(axis=2)
        sums = np.nansum(self.scores, axis=2)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)

    # -- subsets ----------------------------------------------------------------------
    def with_raters(self, keep: list[int] | np.ndarray) -> RatingSet:
        """A copy keeping only the raters at these positions."""
        keep = [int(k) for k in keep]
        return replace(
            self,
            raters=[self.raters[k] for k in keep],
            scores=self.scores[:, keep, :].copy(),
            problems=list(self.problems),
            exclusions=list(self.exclusions),
        )

    def completeness(self) -> np.ndarray:
        """Per rater: share of the planned (stimulus, repetition) trials with a rating.

        Taken from ``rater_info`` when the input knew the plan (session files, manifest);
        otherwise (a SUREAL dataset, whose raters may repeat stimuli unevenly) the share of
        the stimuli the rater rated at least once.
        """
        if self.rater_info is not None and "completeness" in self.rater_info.columns:
            info = self.rater_info["completeness"]
            return np.array([float(info.get(r, np.nan)) for r in self.raters])
        return np.isfinite(self.scores).any(axis=2).sum(axis=0) / max(self.n_stimuli, 1)


def uneven_counts(scores: np.ndarray, completeness: np.ndarray) -> bool:
    """True when the raters who finished gave some stimuli more ratings than others.

    Finished: every planned trial answered (``completeness`` 1), so that a partial session of
    a full design, which leaves some stimuli with fewer ratings, does not make the design
    unbalanced (the completeness rule handles it). When nobody finished the plan (a manifest
    whose plan the ratings do not follow), the raters who rated every stimulus decide.
    """
    done = np.isfinite(completeness) & (completeness >= 1.0 - 1e-9)
    if not done.any():
        done = np.isfinite(scores).any(axis=2).all(axis=0)
    if not done.any():
        return False
    counts = np.isfinite(scores[:, done]).sum(axis=(1, 2))
    counts = counts[counts > 0]
    return bool(counts.size and counts.min() != counts.max())


def subset_text(rs: RatingSet) -> str:
    """The words the report uses for the first-rating subset of an unbalanced set."""
    why = "block 1 of an adaptive design" if rs.allocation == "adaptive" else \
        "repetitions per stimulus differ"
    n_stim = int(np.isfinite(rs.scores[:, :, 0]).any(axis=1).sum())
    return (f"first rating of each stimulus per rater ({why}): {n_stim} stimuli x "
            f"{rs.n_raters} raters")


def balanced_subset(rs: RatingSet) -> tuple[RatingSet, str]:
    """The ratings that ICC and rater screening may use, and their description.

    A balanced set is used whole (description empty). In an unbalanced one the stimuli that
    got more ratings would weigh more in averages over repetitions and the cells' means would
    differ in precision, so the first rating of each stimulus by each rater (repetition 0:
    block 1 of an adaptive study, a complete matrix) is used instead. Rater positions are kept,
    so indices into the subset's raters are indices into ``rs``'s.
    """
    if rs.subset:
        return rs, rs.subset
    if rs.balanced:
        return rs, ""
    text = subset_text(rs)
    return replace(rs, scores=rs.scores[:, :, :1].copy(), problems=list(rs.problems),
                   exclusions=list(rs.exclusions), subset=text), text


def drop_unrated(rs: RatingSet, source: str, why: str) -> RatingSet:
    """``rs`` without the stimuli that no rater left in it rated, each one named in an
    :class:`InputProblem` from ``source`` saying ``why`` (the rule that removed their raters).

    Every step that removes raters calls this: a stimulus with no rating has no score, and
    one NaN DMOS would otherwise turn every metric statistic into NaN downstream.
    """
    rated = np.isfinite(rs.scores).any(axis=(1, 2))
    if rated.all():
        return rs
    lost = [s for s, r in zip(rs.stimulus_ids, rated, strict=True) if not r]
    if not rated.any():
        raise AnalysisError(f"no stimulus has a rating left after {why}; keep more raters "
                            "(e.g. --outliers none or --min-completeness 0)")
    noun = "stimulus" if len(lost) == 1 else "stimuli"
    problem = InputProblem(source, None, f"{len(lost)} {noun} left out: no remaining rater "
                                         f"rated {'it' if len(lost) == 1 else 'them'} "
                                         f"({why}): {', '.join(lost)}")
    return replace(rs, stimuli=rs.stimuli.loc[rated], scores=rs.scores[rated],
                   problems=[*rs.problems, problem], exclusions=list(rs.exclusions))
