"""Simulated participants: SUREAL's generative model, written through the session store.

For rater ``s``, stimulus ``e`` of content (scene) ``c`` and repetition ``r``::

    rating = clip(Q_e + b_s + sigma_s * N(0, 1) + delta_c * N(0, 1), scale.min, scale.max)

with true quality ``Q_e``, rater bias ``b_s`` (normal, truncated at two standard deviations),
rater inconsistency ``sigma_s`` (uniform) and content ambiguity ``delta_c`` (uniform): the
model of Li & Bampis that SUREAL's maximum-likelihood estimator inverts (it identifies only
``sigma_s**2 + delta_c**2``: a constant moved from every rater to every content changes
nothing); every repetition draws new noise. Outlier raters ignore the stimulus: ``random``
ones answer uniformly on the scale, ``inverted`` ones answer ``min + max - Q_e`` plus their
usual noise (they read the scale backwards).

True quality is a documented function of method and level (:func:`true_quality`): on the
0..100 scale ``Q = 100 - A_m * severity ** gamma_m`` with ``severity = (L + 1 - rank) / L``
for the rank 1..L of a level among the method's L levels (the lowest level, the strongest
distortion, has rank 1 and severity 1; levels 4, 16, 64 step as evenly as 1, 2, 3), per-method
``A_m`` and ``gamma_m`` in :data:`QUALITY_CURVES`; hidden references get
:data:`HIDDEN_REFERENCE_QUALITY`. Other scales are mapped linearly.

Every simulated participant is one session file made by :class:`~session_store.SessionStore`
with the app's own trial schedule, so the analysis reads it exactly like a real one. The truth
is written beside the sessions (``ground_truth.json`` and ``ground_truth_stimuli.csv``), with
what an analysis can recover from clipped ratings (:mod:`.simulate_truth`)."""

from __future__ import annotations

import csv
import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any, Literal

import numpy as np
from tqdm.auto import tqdm

from session_store import SessionStore, TrialResult
from session_store.answers import ENDED_BY_VISION_CHECK
from session_store.errors import StudyError
from session_store.schedule import ScheduleItem, block_trials, make_schedule, uniform_block
from stimuli_manifests import LoadedManifest, Stimulus, load_manifest

from . import __version__
from .panel_progress import QUESTIONNAIRE_EVENT
from .remote import UploadStatus
from .simulate_panel import (
    likert_centres,
    simulated_acuity_check,
    simulated_answers,
    simulated_colour_check,
)
from .simulate_truth import expected_rating, recoverable_dmos
from .simulate_upload import NextBlock, UploadOptions, rate_and_upload

log = logging.getLogger(__name__)

OutlierKind = Literal["random", "inverted"]
TRUTH_JSON = "ground_truth.json"
TRUTH_CSV = "ground_truth_stimuli.csv"
TRUTH_FORMAT = "cgvq-simulation-truth/1"
SESSION_SUFFIX = ".sqlite"

HIDDEN_REFERENCE_QUALITY = 97.0
"""True quality of a hidden reference on the 0..100 scale (near the top, not at it)."""

QUALITY_CURVES: dict[str, tuple[float, float]] = {
    # method: (A = impairment at the strongest level, gamma = how fast milder levels recover)
    "path_tracing": (75.0, 1.3),
    "denoising": (55.0, 1.2),
    "upscaling": (50.0, 1.0),
    "splatting": (65.0, 1.1),
    "frame_interpolation": (45.0, 1.5),
    "vrs": (40.0, 1.4),
}
DEFAULT_CURVE = (55.0, 1.2)
"""Curve of methods not listed above."""

START_TIME = datetime(2026, 1, 1, 9, 0, 0, tzinfo=UTC)
"""Simulated sessions carry fixed, made-up times so that their contents follow the seed."""


MAX_RATERS = 10_000
"""Most raters one simulation makes (each is a session file; with a server, a thread)."""


@dataclass(frozen=True)
class SimulationOptions:
    """The panel to simulate (standard deviations on the 0..100 scale)."""

    raters: int = 20
    outliers: int = 0
    outlier_kind: Literal["random", "inverted", "mixed"] = "random"
    seed: int = 0
    bias_sd: float = 6.0
    bias_limit_sd: float = 2.0  # biases are drawn from N(0, bias_sd) truncated at this many sd
    inconsistency_range: tuple[float, float] = (4.0, 10.0)
    ambiguity_range: tuple[float, float] = (2.0, 6.0)
    repetitions: int | None = None  # None: the manifest's protocol.repetitions
    participant_prefix: str = "sim"
    colour_failures: int = 0  # raters who fail the colour check (when the panel screens)

    def check(self) -> None:
        if not 1 <= self.raters <= MAX_RATERS:
            raise StudyError(f"--raters {self.raters}: simulate from 1 to {MAX_RATERS} raters")
        if not 0 <= self.outliers <= self.raters:
            raise StudyError(
                f"--outliers {self.outliers}: choose between 0 and the number of raters "
                f"({self.raters})"
            )
        if self.outlier_kind not in ("random", "inverted", "mixed"):
            raise StudyError(f"outlier kind {self.outlier_kind!r}: random, inverted or mixed")
        if self.bias_limit_sd <= 0:
            raise StudyError("bias_limit_sd must be positive")
        if self.bias_sd < 0 or min(self.inconsistency_range + self.ambiguity_range) < 0:
            raise StudyError("standard deviations of the simulation must not be negative")
        if self.repetitions is not None and self.repetitions < 1:
            raise StudyError(f"--repetitions {self.repetitions}: use at least 1")
        if not 0 <= self.colour_failures <= self.raters:
            raise StudyError(f"--colour-failures {self.colour_failures}: choose between 0 and "
                             f"the number of raters ({self.raters})")


@dataclass(frozen=True)
class RaterTruth:
    participant: str
    bias: float
    inconsistency: float
    outlier: OutlierKind | None
    seed: int
    session_file: str


def true_quality(stimulus: Stimulus, levels: dict[str, list[int]],
                 scale: tuple[float, float] = (0.0, 100.0)) -> float:
    """Documented true quality of a stimulus (see the module docstring).

    ``levels`` maps each method to its levels in the manifest, in ascending order.
    """
    lo, hi = scale
    if stimulus.is_hidden_reference:
        q100 = HIDDEN_REFERENCE_QUALITY
    else:
        amp, gamma = QUALITY_CURVES.get(stimulus.method, DEFAULT_CURVE)
        ranks = levels[stimulus.method]
        rank = ranks.index(stimulus.level) + 1 if stimulus.level is not None else len(ranks)
        severity = (len(ranks) + 1 - rank) / len(ranks)
        q100 = 100.0 - amp * severity**gamma
    return lo + (hi - lo) * q100 / 100.0


def _method_levels(stimuli: list[Stimulus]) -> dict[str, list[int]]:
    """Each method's distinct levels, ascending (a level's rank is its place here)."""
    out: dict[str, set[int]] = {}
    for s in stimuli:
        if not s.is_hidden_reference and s.level is not None:
            out.setdefault(s.method, set()).add(s.level)
    return {m: sorted(v) for m, v in out.items()}


def _outlier_kinds(opts: SimulationOptions, rng: np.random.Generator) -> list[OutlierKind | None]:
    kinds: list[OutlierKind | None] = [None] * opts.raters
    chosen = rng.choice(opts.raters, size=opts.outliers, replace=False)
    for j, idx in enumerate(sorted(int(i) for i in chosen)):
        if opts.outlier_kind == "mixed":
            kinds[idx] = "random" if j % 2 == 0 else "inverted"
        else:
            kinds[idx] = opts.outlier_kind
    return kinds


def _iso(t: datetime) -> str:
    return t.isoformat(timespec="milliseconds").replace("+00:00", "Z")


@dataclass
class SimulationRun:
    truth_path: Path
    upload: dict[str, UploadStatus] = field(default_factory=dict)
    """participant -> the uploader's final status (with a server)."""


def simulate_panel(manifest_path: str | Path, out_dir: str | Path, opts: SimulationOptions,
                   *, overwrite: bool = False, progress: bool = True) -> Path:
    """Write one session file per simulated rater into ``out_dir``; returns the truth file."""
    return run_simulation(manifest_path, out_dir, opts, overwrite=overwrite,
                          progress=progress).truth_path


@dataclass
class _Panel:
    """What a simulation draws once for the whole panel, and the study facts it rates."""

    loaded: LoadedManifest
    stimuli: list[Stimulus]
    repetitions: int
    participants: list[str]
    out: Path
    scale: tuple[float, float]
    unit: float  # standard deviations are given on 0..100
    levels: dict[str, int]
    quality: dict[str, float]
    scenes: list[str]
    ambiguity: dict[str, float]
    kinds: list[Any]
    rater_seeds: list[int]
    settings: dict[str, Any]
    likert_centres: dict[str, float] = field(default_factory=dict)
    colour_failures: frozenset[int] = frozenset()

    @property
    def lower_is_better(self) -> bool:
        return self.loaded.manifest.scale.direction == "lower_is_better"

    @property
    def n_trials(self) -> int:
        adaptive = self.loaded.manifest.protocol.adaptive_settings()
        if adaptive is not None:  # block 1 holds every stimulus once
            n = len(self.stimuli)
            return n + (adaptive.blocks - 1) * adaptive.trials_per_block(n)
        return len(self.stimuli) * self.repetitions


def _participants(opts: SimulationOptions, upload: UploadOptions | None) -> list[str]:
    """The simulated participants' ids: numbered, or the invited ones when uploading."""
    if upload is None:
        return [f"{opts.participant_prefix}{k + 1:02d}" for k in range(opts.raters)]
    participants = list(upload.tokens)[:opts.raters]
    if len(participants) < opts.raters:
        raise StudyError(f"--raters {opts.raters}, but the invites hold only "
                         f"{len(participants)} participant(s); invite more")
    return participants


def _prepare_output(out: Path, participants: list[str], overwrite: bool) -> None:
    """Refuse to overwrite earlier sessions unless asked; then clear what will be written."""
    if out.exists() and not out.is_dir():
        raise StudyError(f"--out {out} is a file; give a folder for the session files")
    targets = [out / f"{p}{SESSION_SUFFIX}" for p in participants] + [out / TRUTH_JSON,
                                                                       out / TRUTH_CSV]
    if overwrite:  # the whole earlier simulation, also raters this run does not have
        targets += _earlier_sessions(out)
    existing = [t for t in dict.fromkeys(targets) if t.exists()]
    if existing and not overwrite:
        raise StudyError(
            f"{out} already holds simulated sessions ({existing[0].name}, ...); choose another "
            "--out or pass --overwrite"
        )
    _remove_sessions(existing)
    out.mkdir(parents=True, exist_ok=True)


def _remove_sessions(paths: list[Path]) -> None:
    for t in paths:
        for suffix in ("", "-wal", "-shm"):
            Path(str(t) + suffix).unlink(missing_ok=True)


def _earlier_sessions(out: Path) -> list[Path]:
    """The session files an earlier simulation into ``out`` lists in its truth file (none
    when there is no readable one)."""
    try:
        truth = json.loads((out / TRUTH_JSON).read_text(encoding="utf-8"))
        files = [Path(str(r["session_file"])).name for r in truth["raters"]]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return [out / name for name in files if name.endswith(SESSION_SUFFIX)]


def _draw_panel(loaded: LoadedManifest, opts: SimulationOptions, repetitions: int,
                participants: list[str], out: Path) -> _Panel:
    """The seeded truth: qualities, content ambiguities, outlier kinds and rater seeds (in a
    fixed order of draws, so the same seed gives the same panel)."""
    m = loaded.manifest
    stimuli = m.stimuli()
    scale = (m.scale.min, m.scale.max)
    unit = (scale[1] - scale[0]) / 100.0
    levels = _method_levels(stimuli)
    scenes = sorted({s.scene for s in stimuli})
    root = np.random.SeedSequence(opts.seed)
    panel_rng = np.random.default_rng(root.spawn(1)[0])
    ambiguity = {c: float(panel_rng.uniform(*opts.ambiguity_range)) * unit for c in scenes}
    kinds = _outlier_kinds(opts, panel_rng)
    rater_seeds = [int(s.generate_state(1)[0]) for s in root.spawn(opts.raters + 1)[1:]]
    settings = {
        "protocol": m.protocol.model_dump(mode="json"),
        "scale": m.scale.model_dump(mode="json"),
        "simulated": True,
        "simulation": {"model": "sureal-generative", "seed": opts.seed,
                       "repetitions": repetitions, "truth_file": TRUTH_JSON},
    }
    centres, failures = {}, frozenset()
    if m.panel is not None:  # drawn after everything above, so older panels stay the same
        panel_draws = np.random.default_rng(root.spawn(opts.raters + 2)[-1])
        centres = likert_centres(m.panel, panel_draws)
        # the colour-check failures are the last raters that are not outliers
        candidates = [k for k in range(opts.raters) if kinds[k] is None][::-1]
        failures = frozenset(candidates[:opts.colour_failures])
    return _Panel(loaded, stimuli, repetitions, participants, out, scale, unit, levels,
                  {s.id: true_quality(s, levels, scale) for s in stimuli}, scenes, ambiguity,
                  kinds, rater_seeds, settings, centres, failures)


def _simulate_rater(panel: _Panel, opts: SimulationOptions, k: int, bar: Any,
                    upload: UploadOptions | None,
                    on_change: Callable[[], None] | None = None,
                    next_block: NextBlock | None = None) -> RaterTruth:
    """Rater ``k``'s whole session, written through the session store as the app would:
    in an adaptive study block 1, then each later block from ``next_block`` (the study
    server) or, without one, uniform blocks as the app plans them."""
    participant = panel.participants[k]
    seed = panel.rater_seeds[k]
    rng = np.random.default_rng(seed)
    bias = _truncated_normal(rng, opts.bias_sd, opts.bias_limit_sd) * panel.unit
    sigma = float(rng.uniform(*opts.inconsistency_range)) * panel.unit
    truth = RaterTruth(participant, bias, sigma, panel.kinds[k], seed,
                       f"{participant}{SESSION_SUFFIX}")
    items = [ScheduleItem(s.id, s.reference, s.is_hidden_reference) for s in panel.stimuli]
    by_id = {s.id: s for s in panel.stimuli}
    adaptive = panel.loaded.manifest.protocol.adaptive_settings()
    plan = make_schedule(items, 1 if adaptive else panel.repetitions, seed)
    clock = None if upload is not None else START_TIME + timedelta(days=k)
    store = SessionStore.create(
        panel.out / f"{participant}{SESSION_SUFFIX}", participant=participant,
        study_id=panel.loaded.manifest.study_id, manifest_sha256=panel.loaded.sha256,
        seed=seed, app_version=f"{__version__}+simulated", plan=plan, settings=panel.settings,
        created_at=_iso(clock) if clock else None, durable=False,
    )
    now = [clock]  # the made-up clock each change is stamped with (None: real time)
    if clock is not None:
        store.clock = lambda: _iso(now[0])
    changed = on_change or (lambda: None)
    with store:
        changed()
        store.save_preflight([{"name": "simulated", "ok": True,
                               "message": "simulated participant: no display"}], skipped=True)
        store.mark_started(display={"simulated": True})
        answer_rng = np.random.default_rng([seed, 1])
        ended_by = _vision_checks(store, panel, k)
        if ended_by:  # as the app with on_fail: end: no questionnaire, no trial
            store.log_event(ENDED_BY_VISION_CHECK, test=ended_by)
            store.finish(allow_incomplete=True)
            changed()
            return truth
        _answer_panel(store, panel, k, "before", answer_rng)
        block = 1
        while True:
            for trial in store.pending():
                stim = by_id[trial.stimulus]
                rating = _rate(rng, panel.quality[stim.id], bias, sigma,
                               panel.ambiguity[stim.scene], panel.kinds[k], panel.scale,
                               lower_is_better=panel.lower_is_better)
                result, now[0] = _trial_result(rng, rating, now[0])
                if upload is not None and upload.pace_s > 0:
                    time.sleep(upload.pace_s)
                store.record(trial.index, result)
                changed()
                bar.update(1)
            if adaptive is None or block >= adaptive.blocks:
                break
            block += 1
            last = store.plan()[-1].stimulus
            if next_block is None:
                stimuli = uniform_block(items, adaptive.trials_per_block(len(items)), seed,
                                        block, last)
                block_id, issued_by = f"local-b{block}", "session"
            else:
                answer = next_block(store.info.session_id, block, last)
                stimuli, block_id, issued_by = answer["stimuli"], answer["id"], "server"
            store.add_block(block, block_id, block_trials(items, stimuli, store.plan()),
                            issued_by=issued_by)
            changed()
        _answer_panel(store, panel, k, "after", answer_rng)  # as the app: before finishing
        store.finish()
        changed()
    return truth


def _vision_checks(store: SessionStore, panel: _Panel, k: int) -> str:
    """Rater ``k``'s vision checks, in the app's order; the check that ends the session
    (failed with ``on_fail: end``, as ``App._panel`` does it) or empty."""
    definition = panel.loaded.manifest.panel
    vs = definition.vision_screening if definition is not None else None
    if vs is None:
        return ""
    checks = [("colour", lambda: simulated_colour_check(k in panel.colour_failures))] \
        if vs.colour else []
    checks += [("acuity", simulated_acuity_check)] if vs.acuity else []
    for test, check in checks:
        outcome, result = check()
        store.record_screening(test, outcome, result)
        if outcome == "failed" and vs.on_fail == "end":
            return test
    return ""


def _answer_panel(store: SessionStore, panel: _Panel, k: int, when: str,
                  rng: np.random.Generator) -> None:
    """Rater ``k``'s questionnaire answers ``when`` (before or after the trials)."""
    definition = panel.loaded.manifest.panel
    if definition is None:
        return
    for questionnaire in definition.questionnaires_at(when):
        answers = simulated_answers(questionnaire, rng, panel.likert_centres)
        for page, question, value in answers:
            store.record_answer(questionnaire.id, question, value, page=page)
        store.log_event(QUESTIONNAIRE_EVENT, questionnaire=questionnaire.id,
                        outcome="done" if answers else "skipped")


def _write_truth(panel: _Panel, opts: SimulationOptions, raters: list[RaterTruth]) -> Path:
    """``ground_truth.json`` (everything drawn) and the per-stimulus truth CSV."""
    m = panel.loaded.manifest
    regular = [(r.bias, r.inconsistency) for r in raters if r.outlier is None]
    expected = {s.id: expected_rating(panel.quality[s.id], regular, panel.ambiguity[s.scene],
                                      panel.scale) for s in panel.stimuli}
    hidden = {s.reference: s.id for s in panel.stimuli if s.is_hidden_reference}
    dmos = recoverable_dmos(expected, {s.id: hidden[s.reference] for s in panel.stimuli
                                       if s.reference in hidden}, panel.scale[1])
    truth = {
        "format": TRUTH_FORMAT,
        "study_id": m.study_id,
        "manifest_sha256": panel.loaded.sha256,
        "seed": opts.seed,
        "model": ("rating = clip(Q + bias + inconsistency * N(0,1) + ambiguity(content) * "
                  "N(0,1), scale); outliers: random = uniform on the scale, inverted = "
                  "min + max - Q + noise"),
        "quality_model": {
            "formula": "Q = 100 - A * ((L + 1 - level) / L) ** gamma; hidden reference "
                       f"{HIDDEN_REFERENCE_QUALITY}",
            "curves": {meth: dict(zip(("A", "gamma"), QUALITY_CURVES.get(meth, DEFAULT_CURVE),
                                      strict=True)) for meth in panel.levels},
        },
        "scale": {"min": panel.scale[0], "max": panel.scale[1],
                  "direction": "lower_is_better" if panel.lower_is_better else
                  "higher_is_better",
                  "true_quality": "higher is better on every scale; on a lower-is-better "
                                  "scale the slider is set at min + max - rating"},
        "repetitions": panel.repetitions,
        "trials_per_participant": panel.n_trials,
        "allocation": m.protocol.allocation,
        "options": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(opts).items()},
        "contents": [{"scene": c, "ambiguity": panel.ambiguity[c]} for c in panel.scenes],
        "raters": [asdict(r) for r in raters],
        "outliers": [r.participant for r in raters if r.outlier],
        "stimuli": [
            {"id": s.id, "reference": s.reference, "scene": s.scene, "method": s.method,
             "level": s.level, "is_hidden_reference": s.is_hidden_reference,
             "true_quality": panel.quality[s.id], "expected_rating": expected[s.id],
             "true_dmos": dmos.get(s.id)}
            for s in panel.stimuli
        ],
        "truth_note": ("true_quality is the latent quality; ratings are clipped to the scale, "
                       "so what an analysis can recover is expected_rating (the regular "
                       "raters' mean expected clipped rating) and true_dmos (P.910's DMOS of "
                       "those expectations): compare dmos.csv with true_dmos"),
    }
    truth_path = panel.out / TRUTH_JSON
    truth_path.write_text(json.dumps(truth, indent=2) + "\n", encoding="utf-8")
    with open(panel.out / TRUTH_CSV, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(truth["stimuli"][0]))
        writer.writeheader()
        writer.writerows(truth["stimuli"])
    return truth_path


def _check_colour_failures(manifest: Any, opts: SimulationOptions) -> None:
    """Failures of a check the panel does not run, or more of them than there are raters who
    are not outliers, would silently simulate fewer than asked for."""
    if not opts.colour_failures:
        return
    vs = manifest.panel.vision_screening if manifest.panel is not None else None
    if vs is None or not vs.colour:
        raise StudyError(f"--colour-failures {opts.colour_failures}: this manifest's panel does "
                         "not screen colour vision (panel.vision_screening.colour; "
                         "cgvq-study panel adds it)")
    honest = opts.raters - opts.outliers
    if opts.colour_failures > honest:
        raise StudyError(f"--colour-failures {opts.colour_failures}: at most the raters who are "
                         f"not outliers ({honest}) can fail the colour check")


def run_simulation(manifest_path: str | Path, out_dir: str | Path, opts: SimulationOptions,
                   *, overwrite: bool = False, progress: bool = True,
                   upload: UploadOptions | None = None) -> SimulationRun:
    """:func:`simulate_panel`, optionally uploading every session to a study server while
    it is written (raters then run at once, one thread each, with real times)."""
    opts.check()
    loaded: LoadedManifest = load_manifest(manifest_path)
    stimuli = loaded.manifest.stimuli()
    if not stimuli:
        raise StudyError(f"{manifest_path}: the manifest has no stimuli to rate")
    if not loaded.manifest.conditions:
        raise StudyError(f"{manifest_path}: the manifest lists no test videos (conditions), "
                         "only references; add conditions (cgvq-study init) before simulating")
    _check_colour_failures(loaded.manifest, opts)
    if opts.repetitions is not None and loaded.manifest.protocol.adaptive_settings():
        raise StudyError(f"--repetitions {opts.repetitions}: this manifest allocates trials "
                         "adaptively (protocol.allocation); its blocks, not repetitions, set "
                         "the trials")
    repetitions = opts.repetitions or loaded.manifest.protocol.repetitions
    if len(stimuli) == 1 and repetitions > 1:
        raise StudyError("a single stimulus cannot be repeated without showing it twice in a "
                         "row; use --repetitions 1")
    out = Path(out_dir)
    participants = _participants(opts, upload)
    _prepare_output(out, participants, overwrite)
    panel = _draw_panel(loaded, opts, repetitions, participants, out)

    bar = tqdm(total=opts.raters * panel.n_trials, desc="simulate", unit="rating",
               disable=not progress)
    t0 = time.monotonic()

    def rater(k: int, on_change: Callable[[], None] | None = None,
              next_block: NextBlock | None = None) -> RaterTruth:
        return _simulate_rater(panel, opts, k, bar, upload, on_change, next_block)

    statuses: dict[str, UploadStatus] = {}
    try:
        if upload is None:
            raters = [rater(k) for k in range(opts.raters)]
        else:
            raters, statuses = rate_and_upload(rater, participants, out, upload, t0, SESSION_SUFFIX)
    except KeyboardInterrupt:
        if upload is None:  # a part of a panel, without its truth, would pass for a panel
            _remove_sessions([out / f"{p}{SESSION_SUFFIX}" for p in participants])
        raise
    finally:
        bar.close()
    truth_path = _write_truth(panel, opts, raters)
    log.info("simulated %d raters (%d outliers) x %d trials into %s", opts.raters,
             opts.outliers, panel.n_trials, out)
    return SimulationRun(truth_path, statuses)


def _truncated_normal(rng: np.random.Generator, sd: float, limit_sd: float) -> float:
    """N(0, sd) redrawn until within +-limit_sd standard deviations (the panel has no
    accidental extreme raters: those are what the outlier option is for)."""
    while True:
        value = float(rng.normal(0.0, sd))
        if sd == 0.0 or abs(value) <= limit_sd * sd:
            return value


def _rate(rng: np.random.Generator, q: float, bias: float, sigma: float, delta: float,
          outlier: OutlierKind | None, scale: tuple[float, float], *,
          lower_is_better: bool = False) -> float:
    """One rating on the scale as the participant moves it: on a lower-is-better scale a
    rater who sees quality ``q`` (a higher-is-better reading) puts the slider at
    ``min + max - q``, which the analysis mirrors back."""
    lo, hi = scale
    noise = sigma * rng.standard_normal() + delta * rng.standard_normal()
    if outlier == "random":
        value = rng.uniform(lo, hi)
    elif outlier == "inverted":
        value = lo + hi - q + bias + noise
    else:
        value = q + bias + noise
    if lower_is_better:
        value = lo + hi - value
    return float(np.clip(value, lo, hi))


def _trial_result(rng: np.random.Generator, rating: float,
                  clock: datetime | None) -> tuple[TrialResult, datetime | None]:
    """Plausible behaviour around a rating: response time, switches, viewing split.
    ``clock`` None: real time (the trial ends now)."""
    rt = float(rng.lognormal(np.log(6000.0), 0.35))
    toggles = int(rng.poisson(3))
    on_ref = rt * float(rng.uniform(0.3, 0.5))
    if clock is None:
        answered = datetime.now(UTC)
        presented = answered - timedelta(milliseconds=rt)
    else:
        presented = clock
        answered = presented + timedelta(milliseconds=rt)
    result = TrialResult(
        rating=rating, rt_ms=rt, n_toggles=toggles, ms_on_reference=on_ref,
        ms_on_test=rt - on_ref, presented_at=_iso(presented),
        slider_first_move_ms=rt * float(rng.uniform(0.5, 0.9)), answered_at=_iso(answered),
        details={"simulated": True},
    )
    pause = timedelta(milliseconds=float(rng.uniform(400, 1500)))
    return result, None if clock is None else answered + pause
