"""What an experimenter should know about a study folder before sending it out.

:func:`check_study` validates the manifest, files, checksums, decodability, durations, frame
rates and sizes of each test/reference pair, and whether the player can lay the largest video
out on the minimum display (which is why this lives with the player, not with the study folder).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from tqdm import tqdm

from session_store.study_folder import BRIEFING_NAME, CONSENT_NAME, SESSIONS_DIR, Study
from stimuli_manifests import (
    DisplayRequirements,
    StimuliError,
    VideoInfo,
    validate_manifest,
)
from stimuli_manifests.balance import Cell, missing_cells
from stimuli_manifests.from_folder.level_order import LevelSample, level_order_warnings
from stimuli_manifests.from_folder.pixel_sample import PixelSample
from stimuli_manifests.from_folder.probe import decode_findings
from stimuli_manifests.lossless import LOSSLESS_DECODER_NAMES
from stimuli_manifests.pairs import pair_mismatches
from stimuli_manifests.panel import screening_distance_problem

log = logging.getLogger(__name__)

# Refresh rates displays commonly run at; the cadence warning assumes the lowest one that
# meets the study's minimum (a 59 Hz minimum means 60 Hz displays).
COMMON_REFRESH_HZ = (24, 30, 50, 60, 75, 90, 100, 120, 144, 165, 240)


@dataclass
class StudyCheck:
    """What :func:`check_study` found; ``ok`` when no error."""

    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    n_stimuli: int = 0
    n_trials: int = 0
    videos: dict[str, VideoInfo] = field(default_factory=dict)
    samples: dict[str, PixelSample] = field(default_factory=dict, repr=False)

    @property
    def ok(self) -> bool:
        return not self.errors


def check_study(study: Study, *, progress: bool = False) -> StudyCheck:
    """Validate a study folder; never raises for problems it can report."""
    out = StudyCheck()
    m = study.manifest
    report = validate_manifest(study.loaded, verify_checksums=True, probe_videos=False,
                               progress=progress)
    out.errors += report.errors + [f"checksum mismatch: {mm}{_rehash_hint(mm, study)}"
                                   for mm in report.mismatches]
    out.warnings += report.warnings
    stimuli = m.stimuli()
    out.n_stimuli = len(stimuli)
    if not m.conditions:
        out.errors.append("the manifest lists no test conditions, only references: a study "
                          "rates test videos against their references; add conditions to "
                          "manifest.json (or build the folder with cgvq-study init)")
    out.n_trials = len(stimuli) * m.protocol.repetitions
    if len(stimuli) < 2 and m.protocol.repetitions > 1:
        out.errors.append("with one stimulus and repetitions > 1 the same stimulus would be "
                          "shown twice in a row; add stimuli or set repetitions to 1")
    items = [(str(s.id), s.path) for s in [*m.references, *m.conditions]]
    for sid, rel in tqdm(items, desc="decoding videos", unit="video", disable=not progress):
        _probe(study, sid, rel, out)
    for cond in m.conditions:
        a, b = out.videos.get(str(cond.id)), out.videos.get(cond.reference)
        if a is not None and b is not None:
            out.errors += pair_mismatches(str(cond.id), cond.reference, a, b)
    for sid, info in out.videos.items():
        errors, warnings = playback_findings(sid, info, m.display)
        out.errors += errors
        out.warnings += warnings
    if (problem := label_room_problem(out.videos.values(), m.display)) is not None:
        out.errors.append(problem)
    out.warnings += level_order_warnings(
        [LevelSample(c.method, c.reference, c.level, out.samples.get(str(c.id)))
         for c in m.conditions], {str(r.id): out.samples.get(str(r.id)) for r in m.references})
    out.samples.clear()  # a few MB per video: not kept with the result
    if (problem := screening_distance_problem(m)) is not None:
        out.warnings.append(problem)
    scenes = {str(r.id): r.scene or str(r.id) for r in m.references}
    out.warnings += missing_cells(Cell(scenes.get(c.reference, c.reference), c.method, c.level)
                                  for c in m.conditions)
    out.warnings += _session_files_warning(study.folder)
    out.warnings += _consent_warning(study)
    fps_set = {round(v.fps, 3) for v in out.videos.values()}
    if len(fps_set) > 1:
        out.warnings.append("stimuli use several frame rates: " +
                            ", ".join(f"{f:g}" for f in sorted(fps_set)))
    return out


def _rehash_hint(mismatch: object, study: Study) -> str:
    """The way out for a text edited after its checksum was written (after a pilot, say):
    record the new checksum, then pilot again (participants must see what was piloted)."""
    if str(getattr(mismatch, "stimulus_id", "")) not in (BRIEFING_NAME, CONSENT_NAME):
        return ""
    return (f"; if you edited it on purpose, record its checksum with 'python -m "
            f"stimuli_manifests hash {study.folder / 'manifest.json'}' and pilot again")


def _consent_warning(study: Study) -> list[str]:
    """A study without a consent text: participants would agree to nothing before they
    rate, which an ethics approval rarely allows; a panel that asks about vision collects
    health data, whose consent must be explicit."""
    if study.consent is not None:
        return []
    panel = study.manifest.panel
    vs = panel.vision_screening if panel is not None else None
    health = (" The panel's vision checks collect health data: ask for explicit consent."
              if vs is not None and (vs.colour or vs.acuity) else
              " The panel's questionnaires collect personal data: ask for consent."
              if panel is not None else "")
    return [f"no consent text (consent.md beside the manifest): participants agree to "
            f"nothing before they rate.{health} See the docs: Ethics and privacy"]


def _session_files_warning(folder: Path) -> list[str]:
    """Session files in the study's own sessions folder (a pilot run without
    ``--sessions-dir``) travel with the folder to every participant."""
    found = sorted((folder / SESSIONS_DIR).glob("*.sqlite"))
    if not found:
        return []
    names = ", ".join(p.stem for p in found[:5]) + (f" and {len(found) - 5} more"
                                                     if len(found) > 5 else "")
    return [f"{SESSIONS_DIR}/ holds {len(found)} session file(s) ({names}): sent with the "
            "study folder, they reach every participant; move pilots out (run --sessions-dir "
            "puts them elsewhere)"]


# How to raise the display requirements: in the manifest of a study, with init's options
# before a manifest exists.
_RAISE_SIZE = {"manifest": "raise display.min_width/min_height in the manifest",
               "init": "pass a larger --min-display"}
_RAISE_HZ = {"manifest": "raise display.min_refresh_hz in the manifest",
             "init": "pass a higher --min-refresh-hz"}


def playback_findings(sid: str, info: VideoInfo, disp: DisplayRequirements, *,
                      settings: Literal["manifest", "init"] = "manifest",
                      transcoding: bool = False) -> tuple[list[str], list[str]]:
    """(errors, warnings) on showing one video frame-accurately on the study's minimum
    display: 1:1 pixels, every frame shown, an even cadence, a lossless codec.
    ``transcoding``: the video is a source init is making a lossless copy of."""
    errors: list[str] = []
    warnings: list[str] = []
    if info.width > disp.min_width or info.height > disp.min_height:
        errors.append(
            f"{sid}: {info.width}x{info.height} does not fit the minimum display "
            f"{disp.min_width}x{disp.min_height} at 1:1 pixels; {_RAISE_SIZE[settings]} or "
            "use smaller videos")
    if info.fps > disp.min_refresh_hz + 1.5:
        errors.append(
            f"{sid}: {info.fps:g} fps is faster than the minimum refresh rate "
            f"{disp.min_refresh_hz:g} Hz: frames would be skipped on such a display; "
            f"{_RAISE_HZ[settings]} or render at a lower frame rate")
    else:
        nominal = next((hz for hz in COMMON_REFRESH_HZ if hz >= disp.min_refresh_hz - 1.5),
                       round(disp.min_refresh_hz))
        ratio = nominal / info.fps
        if abs(ratio - round(ratio)) > 0.01:
            warnings.append(
                f"{sid}: {info.fps:g} fps on a {nominal} Hz display holds frames for "
                f"{math.floor(ratio)} and {math.ceil(ratio)} refreshes in turn (uneven "
                "motion); frame rates that divide the refresh rate play evenly")
    if info.duration < 0.5:
        warnings.append(f"{sid}: only {info.duration:.2f} s long")
    if info.kind == "video" and info.codec == "h264" and not _may_be_lossless_h264(info):
        warnings.append(f"{sid}: H.264 in profile {info.profile or 'unknown'} ({info.pix_fmt}) "
                        "is lossy (only High 4:4:4 Predictive can be lossless); make sure it is "
                        "close enough to the render for a quality study")
    elif info.kind == "video" and info.codec not in LOSSLESS_DECODER_NAMES | {"h264"}:
        warnings.append(f"{sid}: codec {info.codec}; make sure decoding is lossless "
                        "enough for a quality study")
    if info.needs_conversion and transcoding:
        warnings.append(f"{sid}: {info.bit_depth}-bit{' with alpha' if info.has_alpha else ''}"
                        f" ({info.pix_fmt}); its copy holds 8-bit RGB, what the player shows")
    elif info.needs_conversion:
        warnings.append(f"{sid}: {info.bit_depth}-bit{' with alpha' if info.has_alpha else ''}"
                        f" ({info.pix_fmt}); the player shows it as 8-bit RGB, and cgvqm scores "
                        "it only with --allow-convert (init --transcode stores 8-bit copies)")
    return errors, warnings


def _may_be_lossless_h264(info: VideoInfo) -> bool:
    """Only H.264's High 4:4:4 profiles have a lossless mode (x264's qp 0 and its RGB mode
    write them); every other profile quantises, and 4:2:0 also halves the colour."""
    return bool(info.profile) and "4:4:4" in str(info.profile)


def label_room_problem(videos: Iterable[VideoInfo], disp: DisplayRequirements, *,
                       settings: Literal["manifest", "init"] = "manifest") -> str | None:
    """Why the largest video leaves no room for the test/reference label, if it does not."""
    videos = list(videos)
    if not videos:
        return None
    big = (max(v.width for v in videos), max(v.height for v in videos))
    if big[0] <= disp.min_width and big[1] <= disp.min_height and not _label_fits(
            (disp.min_width, disp.min_height), big):
        return (f"videos of {big[0]}x{big[1]} leave no room for the test/reference label on "
                f"the minimum display {disp.min_width}x{disp.min_height}, so the pre-flight "
                f"would refuse such screens; {_RAISE_SIZE[settings]}")
    return None


def _label_fits(window: tuple[int, int], video: tuple[int, int]) -> bool:
    """Whether the viewing screen has room beside the video for its label (as the app
    lays it out with the shipped font)."""
    from .fonts import Fonts
    from .layout import viewing_layout
    from .screens.draw import LABEL_REFERENCE, LABEL_TEST

    lay = viewing_layout(window, video, Fonts(), labels=[LABEL_TEST, LABEL_REFERENCE],
                         progress="Trial 1 of 1", hints=[], notice=[])
    return lay.label is not None


def _probe(study: Study, sid: str, rel: str, out: StudyCheck) -> None:
    """Decode the video in full, as ``init`` does: a file whose container promises more
    frames than decode, or whose decoder reports damage, is an error here too, and the
    frame count compared across a pair is the one the player will show."""
    try:
        path = study.loaded.resolve(rel, field=f"{sid}.path")
    except StimuliError as exc:
        out.errors.append(f"{sid}: {exc}")
        return
    if not path.exists():
        return  # already reported by validate_manifest
    found = decode_findings(path)
    if found.error is not None:
        out.errors.append(f"{sid}: {path.name} {found.error}")
        return
    assert found.info is not None
    out.videos[sid] = found.info
    if found.sample is not None:
        out.samples[sid] = found.sample
    out.warnings += [f"{sid}: {w}" for w in found.warnings]
