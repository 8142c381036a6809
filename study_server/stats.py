"""The dashboard's statistics, recomputed in the background at most every N seconds.

A request never computes anything heavy: it reads the last :class:`StatsSnapshot` and shows
its age. The worker thread wakes when uploads arrive (:meth:`StatsWorker.poke`) but computes
at most once per ``stats_every_s``, and only when the database changed.
"""

from __future__ import annotations

import json
import logging
import statistics
import threading
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING, Any

from session_store.ratings_csv import RATINGS_COLUMNS, tidy_row
from session_store.records import utc_now

from .ingest import parse_time
from .stopping import StoppingStatus, WidthPoint, evaluate
from .worker import REST_FACTOR, ThrottledWorker

if TYPE_CHECKING:
    from .analysis_adapter import StudyFigures
    from .config import ServerConfig
    from .storage import ServerStore
    from .study_files import StudyVersion

log = logging.getLogger(__name__)

RATE_WINDOW = timedelta(hours=1)


@dataclass
class ParticipantStats:
    participant: str
    n_ratings: int = 0
    median_trial_s: float | None = None
    mean_toggles: float | None = None
    mean_viewing_s: float | None = None
    timing: str | None = None
    """``vsync``, a pacing mode, or unknown."""
    dropped_frames: int = 0
    requeued: int = 0
    preflight_skipped: bool | None = None
    preflight_failed: list[str] = field(default_factory=list)
    hidden_reference_mean: float | None = None
    panel_r: float | None = None
    removed_by_screening: str | None = None
    simulated: bool = False
    answers: int = 0
    """Questionnaire answers received (counts only: the dashboard never shows answers)."""
    vision: dict[str, str] = field(default_factory=dict)
    """Vision check -> outcome (passed, failed, inconclusive)."""
    unreadable: int = 0
    """Stored entries the statistics could not read (skipped; shown as a flag)."""


@dataclass
class StatsSnapshot:
    computed_at: str | None = None
    """UTC time of the computation (None: not computed yet)."""
    seconds: float = 0.0
    marker: tuple[int, ...] | None = None
    n_ratings: int = 0
    participants: dict[str, ParticipantStats] = field(default_factory=dict)
    per_stimulus: dict[str, int] = field(default_factory=dict)
    target_per_stimulus: int = 0
    planned_per_participant: int = 0
    study: StudyFigures | None = None
    figures: dict[str, bytes] = field(default_factory=dict)
    error: str | None = None
    has_panel: bool = False
    """The manifest asks questionnaires or screens vision."""
    limits: CellLimits = field(default_factory=lambda: CellLimits())
    panel_answered: int = 0
    """Participants who answered at least one questionnaire question."""
    panel_screened: int = 0
    panel_failed: int = 0
    allocation: str = "full"
    """The manifest's allocation policy; ``adaptive`` holds its settings."""
    adaptive: dict[str, Any] | None = None
    stopping: StoppingStatus | None = None
    """Where the study stands against the stopping rule's target (None: no target)."""
    other_versions: int = 0
    """Participants whose sessions ran an earlier manifest version (``serve --new-version``):
    their ratings are not in the statistics, as the report refuses them under this one."""

    def age_s(self) -> float | None:
        t = parse_time(self.computed_at)
        return None if t is None else (datetime.now(UTC) - t).total_seconds()


def _num(x: Any) -> float | None:
    return float(x) if isinstance(x, int | float) and not isinstance(x, bool) else None


def _obj(x: Any) -> dict[str, Any]:
    """``x`` when it is a JSON object, else empty: a stored body may hold any JSON type."""
    return x if isinstance(x, dict) else {}


@dataclass
class _Samples:
    """Per-participant samples, summarised once every entry was read."""

    rts: list[float] = field(default_factory=list)
    toggles: list[float] = field(default_factory=list)
    viewing: list[float] = field(default_factory=list)
    hidden: list[float] = field(default_factory=list)


def _add_rating(ps: ParticipantStats, acc: _Samples, body: dict[str, Any]) -> None:
    row = _obj(body.get("row"))
    ps.n_ratings += 1
    rt = _num(row.get("rt_ms"))
    if rt is not None:
        acc.rts.append(rt / 1000.0)
    t = _num(row.get("n_toggles"))
    if t is not None:
        acc.toggles.append(t)
    ref, test = _num(row.get("ms_on_reference")), _num(row.get("ms_on_test"))
    if ref is not None and test is not None:
        acc.viewing.append((ref + test) / 1000.0)
    ps.dropped_frames += int(_num(row.get("dropped_frames")) or 0)
    rating = _num(row.get("rating"))
    if row.get("is_hidden_reference") and rating is not None:
        acc.hidden.append(rating)


def _add_entry(ps: ParticipantStats, acc: _Samples, kind: str, body: dict[str, Any]) -> None:
    """One entry's contribution; every structured field is type-checked (one participant's
    odd body must not stop the statistics for everyone)."""
    if kind == "rating":
        _add_rating(ps, acc, body)
    elif kind == "answer":
        ps.answers += 1
    elif kind == "screening":
        ps.vision[str(body.get("test"))] = str(body.get("outcome"))
    elif kind == "requeue":
        ps.requeued += 1
        details = _obj(_obj(body.get("presentation")).get("details"))
        ps.dropped_frames += int(_num(details.get("dropped_frames")) or 0)
    elif kind == "preflight":
        results = body.get("results")
        # Over every run of the session: one run with the check skipped marks it for good.
        ps.preflight_skipped = ps.preflight_skipped or bool(body.get("skipped"))
        failed = [str(r.get("name")) for r in (results if isinstance(results, list) else [])
                  if isinstance(r, dict) and not r.get("ok")]
        ps.preflight_failed = list(dict.fromkeys([*ps.preflight_failed, *failed]))
    elif kind == "session":
        settings = _obj(body.get("settings"))
        ps.simulated = bool(settings.get("simulated"))
        mode = settings.get("timing_mode")
        if isinstance(mode, str):
            ps.timing = mode
    elif kind == "start":
        display = _obj(body.get("display"))
        if ps.timing is None and "vsync" in display:
            ps.timing = "vsync" if display.get("vsync") else "no vsync"
        elif ps.timing is None and display.get("simulated"):
            ps.timing = "simulated"


def participant_stats(rows: list[tuple[str, str, str, str, str]]
                      ) -> dict[str, ParticipantStats]:
    """Per-participant behaviour from the entries (participant, sha, kind, body JSON,
    session id). An entry that cannot be read is skipped and counted in
    ``ParticipantStats.unreadable``, never a failure of the whole snapshot."""
    out: dict[str, ParticipantStats] = {}
    samples: dict[str, _Samples] = {}
    for pid, _, kind, text, _ in rows:
        ps = out.setdefault(pid, ParticipantStats(pid))
        acc = samples.setdefault(pid, _Samples())
        try:
            body = json.loads(text)
            if not isinstance(body, dict):
                raise TypeError("the body is not a JSON object")
            _add_entry(ps, acc, kind, body)
        except (ValueError, TypeError, KeyError, AttributeError, OverflowError):
            ps.unreadable += 1
    for pid, ps in out.items():
        acc = samples[pid]
        if acc.rts:
            ps.median_trial_s = statistics.median(acc.rts)
        if acc.toggles:
            ps.mean_toggles = statistics.fmean(acc.toggles)
        if acc.viewing:
            ps.mean_viewing_s = statistics.fmean(acc.viewing)
        if acc.hidden:
            ps.hidden_reference_mean = statistics.fmean(acc.hidden)
    return out


def _tidy(header: dict[str, Any], text: str) -> dict[str, Any] | None:
    """The tidy row of one stored rating entry, or None when it cannot be read."""
    try:
        return tidy_row(header, _obj(json.loads(text)).get("row", {}))
    except (ValueError, TypeError, KeyError, AttributeError, OverflowError):
        return None


def ratings_frame(rows: list[tuple[str, str, str, str, str]], study_id: str) -> Any:
    """The ratings received so far as the tidy ratings table (``cgvq-ratings/1``, each row
    built by :func:`session_store.ratings_csv.tidy_row`, as in an export), for the analysis;
    a row that cannot be read is left out (and counted per participant by
    :func:`participant_stats`)."""
    import pandas as pd

    records = []
    for pid, sha, kind, text, session_id in rows:
        if kind != "rating":
            continue
        header = {"study_id": study_id, "session_id": session_id, "participant": pid,
                  "manifest_sha256": sha}
        record = _tidy(header, text)
        if record is not None:
            records.append(record)
    return pd.DataFrame.from_records(records, columns=list(RATINGS_COLUMNS))


class StatsWorker:
    """Background recomputation of :class:`StatsSnapshot` (see the module doc)."""

    def __init__(self, config: ServerConfig, store: ServerStore, current: StudyVersion) -> None:
        self.config = config
        self.store = store
        self.current = current
        self.plan = study_plan(current)
        # What the manifest says is known before any statistics: a restarted server's page
        # never shows "0 / 0" trials while its first computation waits.
        self._snapshot = self.plan.apply(StatsSnapshot())
        self._snapshot.target_per_stimulus = self._target_per_stimulus()
        self._lock = threading.Lock()
        self._worker = ThrottledWorker("dashboard-stats", config.stats_every_s, self.refresh,
                                       on_error=self._failed, rest_factor=REST_FACTOR)

    def start(self) -> None:
        self._worker.start()

    def stop(self) -> None:
        self._worker.stop()

    def poke(self) -> None:
        self._worker.poke()

    def snapshot(self) -> StatsSnapshot:
        with self._lock:
            return self._snapshot

    def _failed(self, exc: Exception) -> None:
        """The dashboard shows what went wrong; the server keeps serving."""
        with self._lock:
            self._snapshot.error = f"{type(exc).__name__}: {exc}"

    def refresh(self, *, force: bool = False) -> StatsSnapshot:
        """Recompute now (when the data changed, or ``force``)."""
        store = self.store
        marker = store.change_marker()
        if not force and marker == self.snapshot().marker:
            return self.snapshot()
        t0 = time.perf_counter()
        rows = store.entries_of_kinds(["session", "start", "preflight", "rating", "requeue",
                                       "answer", "screening"])
        snap = StatsSnapshot(marker=marker)
        snap.participants = participant_stats(rows)
        people = snap.participants.values()
        snap.panel_answered = sum(ps.answers > 0 for ps in people)
        snap.panel_screened = sum(bool(ps.vision) for ps in people)
        snap.panel_failed = sum("failed" in ps.vision.values() for ps in people)
        current = self.current
        this_version = [r for r in rows if r[1] == current.manifest_sha256]
        snap.other_versions = len({r[0] for r in rows if r[1] != current.manifest_sha256})
        frame = ratings_frame(this_version, current.study_id)
        snap.n_ratings = len(frame)
        self.plan.apply(snap)
        snap.target_per_stimulus = self._target_per_stimulus()
        counts = frame.groupby("stimulus").size().to_dict() if len(frame) else {}
        snap.per_stimulus = {s: int(counts.get(s, 0)) for s in self.plan.stimuli}
        from .analysis_adapter import analyse, loaded_manifest, panel_correlation

        loaded = loaded_manifest(current.manifest_bytes, current.manifest_sha256)
        for pid, r in panel_correlation(frame, loaded).items():
            if pid in snap.participants:
                snap.participants[pid].panel_r = r
        if len(frame):
            snap.study = analyse(frame, loaded)
            snap.figures = dict(snap.study.figures)
            for pid, reason in snap.study.removed_reasons.items():
                if pid in snap.participants:
                    snap.participants[pid].removed_by_screening = reason
        current = self._record_widths(snap) if len(frame) else None
        if self.config.stopping.is_set:
            points = [WidthPoint(*row) for row in store.width_history()]
            snap.stopping = evaluate(self.config.stopping, points, snap.n_ratings, current)
        snap.seconds = time.perf_counter() - t0
        snap.computed_at = utc_now()
        with self._lock:
            self._snapshot = snap
        return snap

    def _record_widths(self, snap: StatsSnapshot) -> WidthPoint | None:
        """Keep the conditions' DMOS interval widths with the number of raters behind them;
        the point of the data as it is now (None: no widths to judge)."""
        d = snap.study.dmos if snap.study is not None else None
        if d is None or not len(d):
            return None
        cond = d[~d["is_hidden_reference"].astype(bool)]
        width = (cond["ci95_high"] - cond["ci95_low"]).astype(float)
        if (cond["dmos"].notna() & width.isna()).any():
            return None  # a DMOS with too few raters for an interval: no width to judge yet
        width = width[width.abs() < float("inf")]  # no DMOS (its reference unrated): left out
        if not len(width) or snap.study.n_raters < 2:
            return None
        point = WidthPoint(snap.study.n_raters, snap.study.n_ratings, float(width.mean()),
                           float(width.max()))
        self.store.record_widths(point.raters, point.ratings, point.mean_width,
                                 point.max_width, utc_now())
        return point

    def _target_per_stimulus(self) -> int:
        """Ratings each stimulus gets when everyone expected has rated. Everyone invited is
        expected, but a participant who withdrew in the app never will rate again (their
        ratings are left out of everything)."""
        withdrew = {x.participant for x in self.store.sessions() if x.closed_as == "withdrawn"}
        expected = [p for p in self.store.participants() if p.participant not in withdrew]
        raters = self.config.target_raters or max(len(expected), 1)
        return round(raters * self.plan.planned_per_participant
                     / max(len(self.plan.stimuli), 1))

    def rate_per_hour(self) -> float:
        """Ratings *given* per hour over the last hour (or since the first session, when the
        study is younger), asked per request: a rate kept in the snapshot froze when uploads
        stopped, and promised a completion that was not coming. A rating counts by when it
        was given (the participant's clock corrected by its measured offset), not when it
        arrived: answers queued offline for a day and sent in one burst are no pace."""
        start = datetime.now(UTC) - RATE_WINDOW
        recent = 0
        for client_at, offset_ms in self.store.ratings_received_since(
                start.isoformat(timespec="milliseconds").replace("+00:00", "Z")):
            given = parse_time(client_at)
            recent += given is None or given + timedelta(milliseconds=offset_ms or 0) >= start
        if not recent:
            return 0.0
        first = min((s.first_received for s in self.store.sessions()), default=None)
        window_h = RATE_WINDOW.total_seconds() / 3600
        t_first = parse_time(first)
        if t_first is not None:
            window_h = min(window_h, max((datetime.now(UTC) - t_first).total_seconds() / 3600,
                                         1 / 60))
        return recent / window_h


@dataclass(frozen=True)
class CellLimits:
    """Where the dashboard marks a participant's cell: the report's data-quality thresholds
    (:data:`analysis.thresholds.THRESHOLDS`), with the hidden-reference share turned into a
    rating on this study's scale, so that the page and the report flag the same raters."""

    panel_r: float = 0.75
    hidden_reference: float = 50.0
    """The mean hidden-reference rating that is marked below it (above it on a scale where
    lower is better)."""
    higher_is_better: bool = True

    def hidden_reference_low(self, mean: float | None) -> bool:
        if mean is None:
            return False
        return mean < self.hidden_reference if self.higher_is_better \
            else mean > self.hidden_reference


@dataclass(frozen=True)
class StudyPlan:
    """What the served manifest says about the study, read once when the server starts."""

    stimuli: tuple[str, ...]
    has_panel: bool
    allocation: str
    adaptive: dict[str, Any] | None
    planned_per_participant: int
    limits: CellLimits = CellLimits()

    def apply(self, snap: StatsSnapshot) -> StatsSnapshot:
        snap.limits = self.limits
        snap.has_panel = self.has_panel
        snap.allocation = self.allocation
        snap.adaptive = self.adaptive
        snap.planned_per_participant = self.planned_per_participant
        snap.per_stimulus = snap.per_stimulus or {s: 0 for s in self.stimuli}
        return snap


def study_plan(current: StudyVersion) -> StudyPlan:
    from stimuli_manifests import parse_manifest

    m = parse_manifest(json.loads(current.manifest_bytes), source="manifest")
    stimuli = tuple(s.id for s in m.stimuli())
    adaptive = m.protocol.adaptive_settings()
    planned = len(stimuli) * m.protocol.repetitions
    if adaptive is not None:  # block 1 (every stimulus once) and the later blocks
        planned = len(stimuli) + (adaptive.blocks - 1) * adaptive.trials_per_block(len(stimuli))
    from analysis.thresholds import THRESHOLDS

    share, scale = THRESHOLDS["hidden_reference"], m.scale
    higher = scale.direction == "higher_is_better"
    limits = CellLimits(THRESHOLDS["loo_r"], scale.min + share * (scale.max - scale.min)
                        if higher else scale.max - share * (scale.max - scale.min), higher)
    return StudyPlan(stimuli, m.panel is not None, m.protocol.allocation,
                     None if adaptive is None else adaptive.model_dump(), planned, limits)
