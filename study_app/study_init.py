"""``cgvq-study init``: from a folder of a researcher's renders to a study folder.

Maps the files (pattern or CSV), probes and fully decodes every one, and collects every
problem before writing anything: unmapped ids, duplicates, missing references, undecodable
files, test videos that differ from their reference, and videos the player could not show
frame-accurately on the study's minimum display (size, frame rate, decode speed). Only a
folder without problems becomes a study: copies (or lossless transcodes) under
``STUDY/videos/`` and a manifest with checksums. Re-running reports what changed. It lives
with the player because "can the player show it" is the player's rule (see
:mod:`study_app.study_check` and :mod:`study_app.preflight`).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from session_store.errors import StudyError
from session_store.study_folder import (
    MANIFEST_NAME,
    SERVER_STATE_DIR,
    SERVER_STATE_FILE,
    SESSIONS_DIR,
)
from stimuli_manifests import (
    DisplayRequirements,
    Manifest,
    Protocol,
    StimuliError,
    load_manifest,
)
from stimuli_manifests.balance import Cell, missing_cells
from stimuli_manifests.from_folder.build import (
    StudyChanges,
    build_manifest,
    compare,
    delete_stale,
    materialise,
    place,
    shared_paths,
)
from stimuli_manifests.from_folder.level_order import LevelSample, level_order_warnings
from stimuli_manifests.from_folder.mapping import (
    DEFAULT_REFERENCE_PATTERN,
    DEFAULT_TEST_PATTERN,
    FolderMapping,
    MappedVideo,
    Problem,
    map_by_csv,
    map_by_pattern,
)
from stimuli_manifests.from_folder.probe import ProbedVideo, probe_files
from stimuli_manifests.from_folder.suggest import suggest_patterns
from stimuli_manifests.lossless import LosslessCodec
from stimuli_manifests.manifest_io import manifest_to_json
from stimuli_manifests.model import is_valid_id
from stimuli_manifests.pairs import pair_mismatches

from .init_choices import (
    InitChoices,
    read_choices,
    resolved_path,
    stored_path,
    write_choices,
)
from .preflight import MAX_PAIR_DECODE_S
from .study_check import label_room_problem, playback_findings


@dataclass
class InitOptions:
    """What ``cgvq-study init`` was asked to do."""

    folder: Path
    out: Path
    mapping_csv: Path | None = None
    test_pattern: str = DEFAULT_TEST_PATTERN
    reference_pattern: str = DEFAULT_REFERENCE_PATTERN
    study_id: str | None = None
    transcode: LosslessCodec | None = None
    min_display: tuple[int, int] | None = None
    """Replaces the minimum screen size of the previous manifest (else of the defaults)."""
    min_refresh_hz: float | None = None
    """Replaces the minimum refresh rate of the previous manifest (else of the defaults)."""
    viewing_distance_cm: float | None = None
    """Replaces the seating instruction of the previous manifest; 0 removes it."""
    force: bool = False
    progress: bool = False


@dataclass
class InitResult:
    """What was found and done; ``manifest`` is None when problems stopped the run."""

    mapping: FolderMapping
    probes: dict[Path, ProbedVideo] = field(default_factory=dict)
    study_probes: dict[Path, ProbedVideo] = field(default_factory=dict)
    problems: list[Problem] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    manifest: Manifest | None = None
    changes: StudyChanges | None = None
    manifest_written: bool = False
    suggestion: str = ""
    """Patterns read off the names that map the folder (checked), when the given ones left
    scenes without a reference and files unmatched (per-method folders read as scenes)."""

    @property
    def ok(self) -> bool:
        return not self.problems


def init_study(opts: InitOptions) -> InitResult:
    """Build (or update) the study folder ``opts.out`` from the videos in ``opts.folder``."""
    folder, out = opts.folder.resolve(), opts.out.resolve()
    if not folder.is_dir():
        raise StudyError(f"{opts.folder} is not a folder of videos")
    if out == folder:
        raise StudyError("--out must be a new folder, not the folder of renders itself")
    blocker = next((p for p in (out, *out.parents) if p.exists() and not p.is_dir()), None)
    if blocker is not None:  # found now, not after probing every video
        raise StudyError(f"--out {opts.out}: {blocker} is a file; give a folder for the study")
    if opts.study_id is not None and not is_valid_id(opts.study_id):
        raise StudyError(f"--study-id {opts.study_id!r} may contain only letters, digits, "
                         "'_', '-' and '.', and must start with a letter or digit")
    previous = _previous_manifest(out)
    display = _display(opts, previous)
    result = InitResult(_map(opts, folder, out))
    if previous is not None and not opts.force:
        _refuse_another_folder(previous, result.mapping, folder, out)
    if not result.mapping.videos and not result.mapping.problems:
        how = f"listed in {opts.mapping_csv}" if opts.mapping_csv else (
            f"matching {opts.reference_pattern!r} or {opts.test_pattern!r}")
        raise StudyError(f"no videos {how} in {opts.folder}"
                         + _what_would_map(opts, folder, out, result.mapping))
    result.problems += result.mapping.problems
    if any(p.kind == "missing reference" for p in result.problems) and \
            opts.mapping_csv is None and result.mapping.unmatched:
        result.suggestion = _suggestion(folder, out, sorted(
            [*result.mapping.unmatched, *(v.path for v in result.mapping.videos)]))
    if not any(v.role == "test" for v in result.mapping.videos):
        how = (f"list them with role 'test' in {opts.mapping_csv}" if opts.mapping_csv else
               f"name them to match --pattern {opts.test_pattern!r}"
               + _what_would_map(opts, folder, out, result.mapping))
        result.problems.append(Problem(
            "no test videos", str(opts.folder),
            f"only references were found; a study needs at least one test video: {how}"))
    why = (f"not listed in {opts.mapping_csv.name}" if opts.mapping_csv else
           "matches no pattern")
    result.warnings += [f"{p}: {why}, left out" for p in result.mapping.unmatched]
    result.warnings += missing_cells(
        [Cell(v.scene, str(v.method), v.level) for v in result.mapping.videos
         if v.role == "test"], [str(p) for p in result.mapping.unmatched])
    result.warnings += result.mapping.warnings
    result.warnings += [
        f"{p.as_posix() if p.parts else '.'}/: {n} single frames (an image sequence), left "
        "out; init takes video files: encode the frames losslessly first (see docs: Bring "
        "your own videos)" for p, n in sorted(result.mapping.frame_sequences.items())]
    paths = [folder / v.path for v in result.mapping.videos]
    result.probes = probe_files(paths, progress=opts.progress)
    result.warnings += _naming_warnings(result.mapping, result.probes, folder)
    result.warnings += _level_order(result.mapping, result.probes, folder)
    result.problems += _shared_references(result.mapping, result.probes, folder)
    _video_problems(result, folder, display, transcoding=opts.transcode is not None)
    placements = place(result.mapping.videos, result.probes, folder, opts.transcode)
    result.problems += shared_paths(placements)  # listed with the others, not after them
    if result.problems:
        return result
    study_id = opts.study_id or (previous.study_id if previous else _default_study_id(out))
    if previous is not None and not opts.force:
        _refuse_if_sessions_would_break(previous, placements, out)
    created = [p for p in (out, *out.parents) if not p.exists()]  # removed again on failure
    out.mkdir(parents=True, exist_ok=True)
    try:
        shas, written = materialise(placements, out, previous, progress=opts.progress)
        if opts.transcode is not None:
            result.study_probes = probe_files([out / p.study_path for p in placements],
                                              progress=opts.progress, desc="probing copies")
            _speed_problems(result, {p.video.stimulus_id: out / p.study_path
                                     for p in placements},
                            result.study_probes, transcoded=True)
    except BaseException:
        _remove_created(created)
        raise
    if result.problems:
        _remove_created(created)
        return result
    manifest = build_manifest(placements, shas, study_id=study_id, previous=previous,
                              display=display, protocol=_protocol(opts, previous))
    result.changes = compare(previous, manifest)
    result.changes.files_written = written
    result.changes.files_deleted = delete_stale(previous, manifest, out)
    result.manifest = manifest
    path = out / MANIFEST_NAME
    text = manifest_to_json(manifest)
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        tmp = path.with_name(path.name + ".part")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
        result.manifest_written = True
    by_name = opts.mapping_csv is None
    write_choices(out, InitChoices(
        opts.test_pattern if by_name and opts.test_pattern != DEFAULT_TEST_PATTERN else None,
        opts.reference_pattern if by_name and opts.reference_pattern !=
        DEFAULT_REFERENCE_PATTERN else None,
        None if by_name else stored_path(out, opts.mapping_csv), opts.transcode,
        stored_path(out, folder)))
    return result


def _display(opts: InitOptions, previous: Manifest | None) -> DisplayRequirements:
    """The requirements asked for; what was not asked for stays as the study had it."""
    base = previous.display if previous else DisplayRequirements()
    update: dict[str, float] = {}
    if opts.min_display is not None:
        update.update(min_width=opts.min_display[0], min_height=opts.min_display[1])
    if opts.min_refresh_hz is not None:
        update["min_refresh_hz"] = opts.min_refresh_hz
    return DisplayRequirements(**{**base.model_dump(), **update})


def _protocol(opts: InitOptions, previous: Manifest | None) -> Protocol | None:
    """The protocol with the seating distance asked for; None when none was asked for (the
    study keeps its protocol, or gets the defaults)."""
    if opts.viewing_distance_cm is None:
        return None
    base = previous.protocol if previous else Protocol()
    seat = opts.viewing_distance_cm or None  # 0 removes the instruction
    return Protocol(**{**base.model_dump(), "viewing_distance_cm": seat})


def _previous_manifest(out: Path) -> Manifest | None:
    path = out / MANIFEST_NAME
    if not path.exists():
        if out.is_dir() and any(out.iterdir()):
            raise StudyError(f"{out} exists, is not empty and holds no {MANIFEST_NAME}; choose "
                             "a new folder for the study")
        return None
    try:
        return load_manifest(path).manifest
    except StimuliError as exc:
        raise StudyError(f"the study's manifest cannot be read, so init cannot update it: "
                         f"{exc}") from None


def _map(opts: InitOptions, folder: Path, out: Path) -> FolderMapping:
    try:
        if opts.mapping_csv is not None:
            return map_by_csv(folder, opts.mapping_csv)
        return map_by_pattern(folder, test_pattern=opts.test_pattern,
                              reference_pattern=opts.reference_pattern, exclude=out)
    except ValueError as exc:
        raise StudyError(str(exc)) from None


def _what_would_map(opts: InitOptions, folder: Path, out: Path, mapping: FolderMapping
                    ) -> str:
    """For a folder the patterns left (nearly) empty: how many videos it holds and the
    patterns, read off their names, that map every one of them (checked), or where to go."""
    if opts.mapping_csv is not None or not mapping.unmatched:
        return ""
    videos = sorted([*mapping.unmatched, *(v.path for v in mapping.videos)])
    found = f" ({len(videos)} video file(s) found, e.g. {mapping.unmatched[0]})"
    hint = _suggestion(folder, out, videos)
    tops = {v.parts[0] for v in videos if len(v.parts) > 1}
    if not hint and len(tops) == 1 and all(len(v.parts) > 2 for v in videos):
        top = tops.pop()  # renders/2024-05-01/scene01/...: one folder too high
        inner = _suggestion(folder / top, out, [PurePosixPath(*v.parts[1:]) for v in videos])
        return (f"{found}; every video is under {top}/: run init on {folder / top}"
                + (f" ({inner.replace('these patterns', 'where these patterns')})"
                   if inner else ""))
    if not hint:
        return (f"{found}; give --reference-pattern and --pattern that match their names, "
                "or list the files in a --mapping CSV (docs: Bring your own videos)")
    return f"{found}; {hint}"


def _suggestion(folder: Path, out: Path, videos: list) -> str:
    """The checked pattern pair for ``videos`` in words, or "" when there is none."""
    hint = suggest_patterns(folder, videos, exclude=out)
    if hint is None:
        return ""
    maps = (f"all {hint.videos}" if not hint.left_out else
            f"{hint.videos} of {len(videos)}, leaving out {', '.join(hint.left_out)}")
    if hint.doubts:
        more = f" (and {len(hint.doubts) - 1} more)" if len(hint.doubts) > 1 else ""
        return (f"these patterns would map {maps} ({hint.scenes} scene(s)): {hint.flags()}, "
                f"but {hint.doubts[0]}{more}: settle that first (or list the files in a "
                "--mapping CSV)")
    return (f"these patterns map {maps} ({hint.scenes} scene(s)): {hint.flags()}. Check the "
            "list init prints: level 1 must be the strongest distortion, or use a --mapping "
            "CSV")


def _default_study_id(out: Path) -> str:
    name = "".join(c if c.isalnum() or c in "_-." else "-" for c in out.name).strip("-.")
    return name if name and is_valid_id(name) else "study"


def _naming_warnings(mapping: FolderMapping, probes: dict[Path, ProbedVideo],
                     folder: Path) -> list[str]:
    """Export slips that are legal but rarely meant: a reference without test videos, and
    a test video byte-identical to its reference or to another test video."""
    out = []
    tested = {v.scene for v in mapping.videos if v.role == "test"}
    out += [f"{v.path}: the reference of scene {v.scene!r} has no test video (check the "
            "names of its test videos)" for v in mapping.videos
            if v.role == "reference" and v.scene not in tested]
    refs = mapping.references()
    ref_of_sha = {probes[folder / r.path].sha256: r for r in refs.values()}
    first: dict[str, MappedVideo] = {}
    for v in sorted((v for v in mapping.videos if v.role == "test"), key=lambda v: v.path):
        sha = probes[folder / v.path].sha256
        ref = refs.get(v.scene)
        if ref is not None and probes[folder / ref.path].sha256 == sha:
            out.append(f"{v.path}: the same file as its reference {ref.path} (byte for byte)")
        elif (other := ref_of_sha.get(sha)) is not None:
            out.append(f"{v.path}: the same file as the reference of scene {other.scene!r}, "
                       f"{other.path} (byte for byte): an export in the wrong folder?")
        elif sha in first:
            out.append(f"{v.path}: the same file as {first[sha].path} (byte for byte)")
        first.setdefault(sha, v)
    return out


def _level_order(mapping: FolderMapping, probes: dict[Path, ProbedVideo],
                 folder: Path) -> list[str]:
    """Methods whose level 1 looks the mildest in pixels (see `level_order`)."""
    refs = {scene: probes[folder / v.path].sample for scene, v in mapping.references().items()}
    tests = [LevelSample(str(v.method), v.scene, int(v.level), probes[folder / v.path].sample)
             for v in mapping.videos if v.role == "test" and v.level is not None]
    return level_order_warnings(tests, refs)


def _shared_references(mapping: FolderMapping, probes: dict[Path, ProbedVideo],
                       folder: Path) -> list[Problem]:
    """Two scenes whose references are one file (a copy or a link into the wrong folder):
    every test of the second would be rated and scored against the first's content."""
    first: dict[str, MappedVideo] = {}
    out = []
    for ref in sorted(mapping.references().values(), key=lambda v: v.path):
        probe = probes[folder / ref.path]
        if probe.info is None:
            continue
        if (other := first.get(probe.sha256)) is not None:
            out.append(Problem("same reference", str(ref.path), (
                f"byte for byte the reference of scene {other.scene!r} ({other.path}): two "
                "scenes cannot share one reference; put scene "
                f"{ref.scene!r}'s own reference there, or make the two one scene")))
        first.setdefault(probe.sha256, ref)
    return out


def _remove_created(created: list[Path]) -> None:
    """Remove the folders this run created (deepest first), with what it wrote into them."""
    if created:
        shutil.rmtree(created[0], ignore_errors=True)
        for folder in created[1:]:
            try:
                folder.rmdir()
            except OSError:
                break


def _video_problems(result: InitResult, folder: Path, display: DisplayRequirements, *,
                    transcoding: bool) -> None:
    """Undecodable files, pair mismatches and what the player cannot show (how fast the
    sources decode only matters when they are not transcoded)."""
    videos = result.mapping.videos
    infos = {}
    for video in videos:
        probe = result.probes[folder / video.path]
        if probe.info is None:
            result.problems.append(Problem(probe.error_kind, str(video.path), str(probe.error)))
            continue
        infos[video.stimulus_id] = probe.info
        result.warnings += [f"{video.path}: {w}" for w in probe.warnings]
        errors, warnings = playback_findings(str(video.path), probe.info, display,
                                             settings="init", transcoding=transcoding)
        result.problems += [Problem("player", str(video.path), e.split(": ", 1)[1])
                            for e in errors]
        result.warnings += warnings
    refs = result.mapping.references()
    for video in videos:
        ref = refs.get(video.scene)
        if video.role != "test" or ref is None:
            continue
        test_info, ref_info = infos.get(video.stimulus_id), infos.get(ref.stimulus_id)
        if test_info is not None and ref_info is not None:
            for message in pair_mismatches(str(video.path), str(ref.path), test_info, ref_info):
                result.problems.append(Problem("mismatch", str(video.path),
                                               message.split(": ", 1)[1]))
            if (problem := _out_of_step(result, folder, video, ref)) is not None:
                result.problems.append(problem)
            if (chroma := _chroma(test_info.pix_fmt)) != (ref_chroma := _chroma(
                    ref_info.pix_fmt)) and chroma and ref_chroma:
                result.warnings.append(
                    f"{video.path}: {test_info.pix_fmt} ({chroma}), its reference {ref.path} "
                    f"is {ref_info.pix_fmt} ({ref_chroma}); the colour resolution differs, "
                    "which is part of what raters and metrics see (an export setting?)")
    if (problem := label_room_problem(infos.values(), display, settings="init")) is not None:
        result.problems.append(Problem("player", "all videos", problem))
    if not transcoding:
        _speed_problems(result, {v.stimulus_id: folder / v.path for v in videos},
                        result.probes, transcoded=False)


def _chroma(pix_fmt: str) -> str:
    """The colour sampling of an FFmpeg pixel format ("4:2:0", "4:4:4"; "" when unknown)."""
    f = pix_fmt.lower()
    if f.startswith(("rgb", "bgr", "gbr", "argb", "abgr", "0rgb", "0bgr", "yuv444",
                     "yuvj444")):
        return "4:4:4"
    if f.startswith(("yuv422", "yuvj422", "nv16", "yuyv422", "uyvy422")):
        return "4:2:2"
    if f.startswith(("yuv420", "yuvj420", "nv12", "nv21", "p010", "yuva420")):
        return "4:2:0"
    return ""


def _out_of_step(result: InitResult, folder: Path, video: MappedVideo,
                 ref: MappedVideo) -> Problem | None:
    """A test whose timestamps skip frame slots its reference's do not (a frame dropped in
    the export): same frame count, but from the gap on it shows what the reference shows
    one frame later, so the comparison and any frame-wise metric are out of step."""
    test, reference = result.probes[folder / video.path], result.probes[folder / ref.path]
    if test.skipped_slots == reference.skipped_slots:
        return None
    return Problem("mismatch", str(video.path), (
        f"its timestamps skip {test.skipped_slots} frame slot(s) and those of its reference "
        f"{ref.path} skip {reference.skipped_slots}: a frame was dropped in an export, so the "
        "two are out of step from there on; re-export the one that skips"))


def _speed_problems(result: InitResult, files: dict[str, Path],
                    probes: dict[Path, ProbedVideo], *, transcoded: bool) -> None:
    """A pair the player's background decoding cannot have ready in time on this machine."""
    refs = result.mapping.references()
    for video in result.mapping.videos:
        ref = refs.get(video.scene)
        if ref is None:
            continue
        test, reference = probes[files[video.stimulus_id]], probes[files[ref.stimulus_id]]
        if test.info is None or reference.info is None:
            continue
        seconds = test.decode_seconds + (0.0 if video.role == "reference"
                                         else reference.decode_seconds)
        if seconds > MAX_PAIR_DECODE_S:
            advice = ("even as a transcode: use shorter or smaller videos" if transcoded else
                      "--transcode makes lossless copies that decode several times faster")
            result.problems.append(Problem(
                "player", video.path.as_posix(),
                f"decoding it with its reference takes {seconds:.1f} s on this computer; the "
                f"player's pre-flight refuses more than {MAX_PAIR_DECODE_S:g} s per pair "
                f"({advice})"))


def _refuse_another_folder(previous: Manifest, mapping: FolderMapping, folder: Path,
                           out: Path) -> None:
    """A re-run that reads another renders folder (a typo, a neighbouring folder) and would
    remove stimuli is refused before anything is probed or deleted: the copies it would
    delete may have taken long to make (``--transcode``). The folder of the last run is in
    init.json; a study without it is refused when no stimulus at all would stay."""
    old = [str(e.id) for e in [*previous.references, *previous.conditions]]
    new = {v.stimulus_id for v in mapping.videos}
    gone = [sid for sid in old if sid not in new]
    if not gone:
        return
    last = read_choices(out)
    made_from = last.renders if last is not None else None
    if made_from is not None and resolved_path(out, made_from) == folder:
        return
    if made_from is None and len(gone) < len(old):
        return
    source = (f"was made from {resolved_path(out, made_from)}" if made_from else
              "holds other stimuli")
    raise StudyError(
        f"{out} {source}; this run reads {folder} and would remove {len(gone)} of its "
        f"{len(old)} stimuli (e.g. {', '.join(gone[:3])}) and delete their copies: give the "
        "folder it was made from, or pass --force to replace them")


def _refuse_if_sessions_would_break(previous: Manifest, placements: list, out: Path) -> None:
    """Changing stimuli under collected ratings would mix ratings of different videos; under
    a served study (its state in ``server/``) it would also replace files its participants
    download by checksum, and their runs would fail."""
    sessions = sorted((out / SESSIONS_DIR).glob("*.sqlite")) if (out / SESSIONS_DIR).is_dir() \
        else []
    served = (out / SERVER_STATE_DIR / SERVER_STATE_FILE).is_file()
    if not sessions and not served:
        return
    old = {str(e.id): (e.metadata.get("source"), e.path)
           for e in [*previous.references, *previous.conditions]}
    new = {p.video.stimulus_id: (p.source_record(), p.study_path.as_posix()) for p in placements}
    if old == new:
        return
    if sessions:
        raise StudyError(
            f"{out} already holds {len(sessions)} session file(s) and its stimuli would change; "
            "ratings of different videos would be mixed: init into a new folder (or pass "
            "--force if no session counts)")
    raise StudyError(
        f"{out} is a served study ({SERVER_STATE_DIR}/{SERVER_STATE_FILE}) and its stimuli "
        "would change under it: its participants download these files by checksum, and "
        "sessions on the server rate the current ones: init into a new folder and serve that "
        "(or pass --force if nobody has been invited)")
