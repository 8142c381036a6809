"""What an experimenter should know about a study folder before sending it out.

:func:`check_study` validates the manifest, files, checksums, decodability, durations, frame
rates and sizes of each test/reference pair, and whether the player can lay the largest video
out on the minimum display (which is why this lives with the player, not with the study folder).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from session_store.study_folder import Study
from stimuli_manifests import StimuliError, VideoInfo, probe_video, validate_manifest

log = logging.getLogger(__name__)


@dataclass
class StudyCheck:
    """What :func:`check_study` found; ``ok`` when no error."""

    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    n_stimuli: int = 0
    n_trials: int = 0
    videos: dict[str, VideoInfo] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.errors


def check_study(study: Study, *, progress: bool = False) -> StudyCheck:
    """Validate a study folder; never raises for problems it can report."""
    out = StudyCheck()
    m = study.manifest
    report = validate_manifest(study.loaded, verify_checksums=True, probe_videos=False,
                               progress=progress)
    out.errors += report.errors + [f"checksum mismatch: {mm}" for mm in report.mismatches]
    out.warnings += report.warnings
    stimuli = m.stimuli()
    out.n_stimuli = len(stimuli)
    out.n_trials = len(stimuli) * m.protocol.repetitions
    if len(stimuli) < 2 and m.protocol.repetitions > 1:
        out.errors.append("with one stimulus and repetitions > 1 the same stimulus would be "
                          "shown twice in a row; add stimuli or set repetitions to 1")
    for ref in m.references:
        _probe(study, str(ref.id), ref.path, out)
    for cond in m.conditions:
        _probe(study, str(cond.id), cond.path, out)
    for cond in m.conditions:
        a, b = out.videos.get(str(cond.id)), out.videos.get(cond.reference)
        if a is None or b is None:
            continue
        if (a.width, a.height) != (b.width, b.height):
            out.errors.append(f"{cond.id}: size {a.width}x{a.height} differs from its reference "
                              f"{cond.reference} ({b.width}x{b.height}); re-encode it")
        if abs(a.fps - b.fps) > 1e-3:
            out.errors.append(f"{cond.id}: {a.fps:g} fps differs from its reference "
                              f"{cond.reference} ({b.fps:g} fps)")
        if a.frame_count != b.frame_count:
            out.errors.append(f"{cond.id}: {a.frame_count} frames, its reference "
                              f"{cond.reference} has {b.frame_count}; both loops must match")
    disp = m.display
    for sid, info in out.videos.items():
        if info.width > disp.min_width or info.height > disp.min_height:
            out.errors.append(
                f"{sid}: {info.width}x{info.height} does not fit the minimum display "
                f"{disp.min_width}x{disp.min_height} at 1:1 pixels; raise display.min_width/"
                "min_height in the manifest or use smaller videos")
        if info.fps > disp.min_refresh_hz + 1.5:
            out.warnings.append(
                f"{sid}: {info.fps:g} fps is faster than the minimum refresh rate "
                f"{disp.min_refresh_hz:g} Hz; frames would be skipped on such a display")
        if info.duration < 0.5:
            out.warnings.append(f"{sid}: only {info.duration:.2f} s long")
        if info.kind == "video" and info.codec not in ("ffv1", "libx264rgb", "h264", "rawvideo",
                                                       "png", "utvideo", "ffvhuff"):
            out.warnings.append(f"{sid}: codec {info.codec}; make sure decoding is lossless "
                                "enough for a quality study")
    if out.videos:
        big = (max(v.width for v in out.videos.values()),
               max(v.height for v in out.videos.values()))
        if big[0] <= disp.min_width and big[1] <= disp.min_height and not _label_fits(
                (disp.min_width, disp.min_height), big):
            out.errors.append(
                f"videos of {big[0]}x{big[1]} leave no room for the test/reference label on the "
                f"minimum display {disp.min_width}x{disp.min_height}, so the pre-flight would "
                "refuse such screens; raise display.min_width/min_height in the manifest")
    fps_set = {round(v.fps, 3) for v in out.videos.values()}
    if len(fps_set) > 1:
        out.warnings.append("stimuli use several frame rates: " +
                            ", ".join(f"{f:g}" for f in sorted(fps_set)))
    return out


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
    try:
        path = study.loaded.resolve(rel, field=f"{sid}.path")
        if not path.exists():
            return  # already reported by validate_manifest
        out.videos[sid] = probe_video(path)
    except StimuliError as exc:
        out.errors.append(f"{sid}: {exc}")
