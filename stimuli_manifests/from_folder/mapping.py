"""Which file of a researcher's folder of renders is which stimulus.

Two ways to say it: a filename pattern (``{scene}/{method}_L{level}.{ext}`` for test videos
and ``{scene}/reference.{ext}`` for references by default), or a CSV the researcher writes
with one row per file (``path,scene,role,method,level,setting``). Both give the same list of
:class:`MappedVideo`; everything that cannot be mapped is a :class:`Problem`, collected rather
than raised, so that one run lists all of them.
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Literal, TextIO

from ..model import is_valid_id
from ..paths import portable_part_problem

Role = Literal["reference", "test"]

DEFAULT_TEST_PATTERN = "{scene}/{method}_L{level}.{ext}"
DEFAULT_REFERENCE_PATTERN = "{scene}/reference.{ext}"
VIDEO_SUFFIXES = frozenset({".mkv", ".mp4", ".mov", ".avi", ".webm", ".nut", ".y4m", ".m4v",
                            ".mpg", ".mpeg", ".ts", ".mxf", ".flv", ".f4v", ".m2ts", ".mts",
                            ".wmv", ".asf", ".ogv", ".3gp", ".vob", ".dv", ".ivf"})
FRAME_SUFFIXES = frozenset({".png", ".exr", ".jpg", ".jpeg", ".tif", ".tiff", ".dpx", ".bmp",
                            ".tga", ".webp"})
"""Single frames: a folder of them is a frame sequence, which init does not take (it is named,
not left out without a word)."""
CSV_COLUMNS = ("path", "scene", "role", "method", "level", "setting")
_PLACEHOLDERS = {
    "scene": r"(?P<scene>[^/]+?)",
    "method": r"(?P<method>[^/]+)",  # greedy: path_traced_4spp is path_traced + 4spp
    "level": r"(?P<level>\d+)",
    "setting": r"(?P<setting>[^/]+?)",
    "ext": r"(?P<ext>[A-Za-z0-9]+)",
}
_ROLE_WORDS = {"reference": "reference", "ref": "reference", "src": "reference",
               "gt": "reference", "ground truth": "reference", "ground_truth": "reference",
               "original": "reference",
               "test": "test", "condition": "test", "distorted": "test", "pvs": "test"}


@dataclass(frozen=True)
class Problem:
    """One reason the folder cannot become a study yet: which file or stimulus, and why."""

    kind: str
    subject: str
    detail: str

    def __str__(self) -> str:
        return f"{self.subject}: {self.detail}"


@dataclass(frozen=True)
class MappedVideo:
    """A file of the folder with its place in the study."""

    path: PurePosixPath
    scene: str
    role: Role
    method: str | None = None
    level: int | None = None
    setting: str | None = None

    @property
    def stimulus_id(self) -> str:
        """``scene`` for a reference, ``scene_method_Llevel`` for a test video."""
        if self.role == "reference":
            return self.scene
        return f"{self.scene}_{self.method}_L{self.level}"


@dataclass
class FolderMapping:
    """The mapped videos, the folder's files nothing mapped, and the problems found."""

    videos: list[MappedVideo] = field(default_factory=list)
    unmatched: list[PurePosixPath] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)
    frame_sequences: dict[PurePosixPath, int] = field(default_factory=dict)
    """Folders holding single frames (an image sequence), with how many."""
    warnings: list[str] = field(default_factory=list)
    """Mapped, but maybe not as meant (a scene name split at its separator)."""

    def references(self) -> dict[str, MappedVideo]:
        return {v.scene: v for v in self.videos if v.role == "reference"}


def compile_pattern(pattern: str, *, required: tuple[str, ...],
                    scenes: list[str] | None = None) -> re.Pattern[str]:
    """A filename pattern with ``{placeholders}`` as a regular expression over relative
    POSIX paths; ``ValueError`` names an unknown or missing placeholder. With ``scenes``,
    ``{scene}`` matches only those names, the longest first."""
    names = re.findall(r"{([^{}]*)}", pattern)
    for name in names:
        if name not in _PLACEHOLDERS:
            raise ValueError(f"pattern {pattern!r}: unknown placeholder {{{name}}}; use "
                             + ", ".join(f"{{{p}}}" for p in _PLACEHOLDERS))
    twice = sorted({n for n in names if names.count(n) > 1} - {"scene"})
    if twice:  # {scene} may repeat (scene01/scene01_dlss_L1.mp4): it must read the same
        raise ValueError(f"pattern {pattern!r} uses {{{twice[0]}}} twice (only {{scene}} may "
                         "appear more than once)")
    if pattern.startswith("/") or ".." in pattern.split("/"):
        raise ValueError(f"pattern {pattern!r} must be relative to the renders folder, "
                         "without '..'")
    if not re.search(r"\.(\{ext\}|[A-Za-z0-9]+)$", pattern):
        raise ValueError(f"pattern {pattern!r} must end in the file's extension: '.{{ext}}' "
                         "(any video) or a literal one such as '.mkv'")
    for name in required:
        if name not in names:
            raise ValueError(f"pattern {pattern!r} needs a {{{name}}} placeholder")
    pieces = dict(_PLACEHOLDERS)
    if scenes:
        alternatives = "|".join(re.escape(n) for n in sorted(scenes, key=len, reverse=True))
        pieces["scene"] = f"(?P<scene>{alternatives})"
    parts, seen = [], set()
    for part in (p for p in re.split(r"({[^{}]*})", pattern) if p):
        if not part.startswith("{"):
            parts.append(re.escape(part))
        elif part[1:-1] in seen:  # a repeated {scene}: the same text again
            parts.append(f"(?P={part[1:-1]})")
        else:
            seen.add(part[1:-1])
            parts.append(pieces[part[1:-1]])
    return re.compile("".join(parts))


@dataclass
class FolderScan:
    """What one walk of a renders folder found (hidden files and ``exclude`` skipped; linked
    folders followed once each: renders often live on another disk)."""

    videos: list[PurePosixPath] = field(default_factory=list)
    """Video files by suffix, sorted."""
    broken: list[Problem] = field(default_factory=list)
    """Video-named symbolic links whose target does not exist: a render the researcher meant
    to include, not a file to leave out without a word."""
    frame_sequences: dict[PurePosixPath, int] = field(default_factory=dict)
    """Folders (the scanned one included) with two or more single frames (PNG, EXR, ...):
    image sequences, with their number of frames."""


def scan_folder(folder: Path, *, exclude: Path | None = None) -> FolderScan:
    """Walk ``folder`` once (a renders folder on a network disk is slow to list)."""
    frames: dict[PurePosixPath, int] = {}
    found = _walk(folder, exclude, frames)
    return FolderScan(
        videos=[rel for rel, target in found if target is None],
        broken=[Problem("broken link", rel.as_posix(), f"is a symbolic link to {target}, "
                        "which does not exist") for rel, target in found if target is not None],
        frame_sequences={k: n for k, n in frames.items() if n >= 2})


def _walk(folder: Path, exclude: Path | None, frames: dict[PurePosixPath, int] | None = None
          ) -> list[tuple[PurePosixPath, str | None]]:
    """(relative path, None) for each video file and (relative path, link target) for each
    broken link, following linked folders once each (a link back up is not a loop); counts
    single frames per folder into ``frames``."""
    out: list[tuple[PurePosixPath, str | None]] = []
    seen: set[str] = set()
    for root, dirs, files in os.walk(folder, followlinks=True):
        real = os.path.realpath(root)
        if real in seen:
            dirs[:] = []
            continue
        seen.add(real)
        here = Path(root)
        if exclude is not None and Path(real).is_relative_to(exclude):
            dirs[:] = []
            continue
        # real folders before links to them (an 'Aaa_current' link to 'sponza' would
        # otherwise be walked first and rename the scene)
        dirs[:] = sorted((d for d in dirs if not d.startswith(".")),
                         key=lambda d: (os.path.islink(os.path.join(root, d)), d))
        for name in files:
            path = here / name
            if name.startswith("."):
                continue
            if frames is not None and path.suffix.lower() in FRAME_SUFFIXES:
                rel_dir = PurePosixPath(here.relative_to(folder).as_posix())
                frames[rel_dir] = frames.get(rel_dir, 0) + 1
            if path.suffix.lower() not in VIDEO_SUFFIXES:
                continue
            rel = PurePosixPath(path.relative_to(folder).as_posix())
            if path.is_file():
                out.append((rel, None))
            elif path.is_symlink():
                out.append((rel, os.readlink(path)))
    return sorted(out)


def map_by_pattern(folder: Path, *, test_pattern: str = DEFAULT_TEST_PATTERN,
                   reference_pattern: str = DEFAULT_REFERENCE_PATTERN,
                   exclude: Path | None = None) -> FolderMapping:
    """Map every video file under ``folder`` with the two filename patterns."""
    test_re = compile_pattern(test_pattern, required=("scene", "method", "level"))
    ref_re = compile_pattern(reference_pattern, required=("scene",))
    scan = scan_folder(folder, exclude=exclude)
    out = FolderMapping(problems=scan.broken, frame_sequences=scan.frame_sequences)
    tests: list[PurePosixPath] = []
    matches = {rel: (ref_re.fullmatch(rel.as_posix()), test_re.fullmatch(rel.as_posix()))
               for rel in scan.videos}
    # a file both patterns match (a loose '{scene}.{ext}' takes every file) is a test video
    # when its scene's reference is among the files only the reference pattern matches
    plain_refs = {r["scene"] for r, t in matches.values() if r and not t}
    for rel, (ref_m, test_m) in matches.items():
        if ref_m and not (test_m and test_m["scene"] in plain_refs):
            out.videos.append(MappedVideo(rel, ref_m["scene"], "reference"))
        elif test_m:
            tests.append(rel)
        else:
            out.unmatched.append(rel)
    # A scene name may hold the separator the pattern puts after it (sponza_atrium_dlss_L1
    # beside sponza_reference): a split at a scene that has a reference, the longest, wins.
    known = compile_pattern(test_pattern, required=("scene", "method", "level"),
                            scenes=list(out.references())) if out.references() else None
    for rel in tests:
        text = rel.as_posix()
        m = (known.fullmatch(text) if known else None) or test_re.fullmatch(text)
        assert m is not None
        out.videos.append(MappedVideo(rel, m["scene"], "test", m["method"],
                                      int(m["level"]), m.groupdict().get("setting")))
    _check(out, f"Rename it to match {reference_pattern!r}, or give --reference-pattern")
    out.warnings += _split_warnings(out, test_pattern)
    out.warnings += case_warnings(out)
    return out


def case_warnings(out: FolderMapping) -> list[str]:
    """Methods (and scenes) whose names differ only in case (``TAA`` and ``taa``): they
    become two methods of the study, which the analysis draws and scores apart."""
    warnings = []
    for what, names in (("methods", {str(v.method) for v in out.videos if v.method}),
                        ("scenes", {v.scene for v in out.videos})):
        groups: dict[str, list[str]] = {}
        for name in sorted(names):
            groups.setdefault(name.casefold(), []).append(name)
        warnings += [f"{what} {' and '.join(repr(n) for n in group)} differ only in case: "
                     f"they are {len(group)} {what} of the study; rename the files (or map "
                     "them in a CSV) if they are one" for group in groups.values()
                     if len(group) > 1]
    return warnings


def _split_warnings(out: FolderMapping, test_pattern: str) -> list[str]:
    """Test videos whose method looks like the rest of a scene name: with
    ``{scene}_{method}``, ``sponza_atrium_dlss_L1`` is method ``atrium_dlss`` of ``sponza``
    unless ``sponza_atrium`` has a reference. Said for every method that holds the separator
    and is found under this scene only: whether its tail (``dlss``, ``xess``) is a method
    elsewhere or not (``sponza_night_xess`` beside ``sponza_ref`` alone), the names cannot
    tell a lost reference from a method with the separator in its name (``path_traced``); a
    method every scene shares is not in doubt."""
    m = re.search(r"{scene}([^{}/]+){method}", test_pattern)
    if m is None:
        return []
    sep = m.group(1)
    tests = [v for v in out.videos if v.role == "test" and v.method]
    scenes_of: dict[str, set[str]] = {}
    for v in tests:
        scenes_of.setdefault(str(v.method), set()).add(v.scene)
    said, warnings = set(), []
    for v in tests:
        method = str(v.method)
        head, _, tail = method.partition(sep)
        if not tail or (v.scene, method) in said or scenes_of[method] != {v.scene}:
            continue
        said.add((v.scene, method))
        warnings.append(f"{v.path}: read as method {method!r} of scene {v.scene!r}; if "
                        f"{v.scene + sep + head!r} is a scene of its own, its reference is "
                        "missing (if not, a --mapping CSV confirms this reading)")
    return warnings


def map_by_csv(folder: Path, csv_path: Path) -> FolderMapping:
    """Map the files a researcher listed in a CSV (``path,scene,role,method,level,setting``;
    paths relative to ``folder``)."""
    out = FolderMapping()
    try:
        with open(csv_path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh, delimiter=_delimiter(fh))
            # as a spreadsheet saves it: any case, empty trailing columns
            columns = [c.strip().lower() for c in reader.fieldnames or [] if c and c.strip()]
            missing = [c for c in ("path", "scene", "role") if c not in columns]
            if missing:
                raise ValueError(f"{csv_path}: missing column(s) {', '.join(missing)}; "
                                 f"expected {','.join(CSV_COLUMNS)}")
            unknown = [c for c in columns if c not in CSV_COLUMNS]
            if unknown:
                raise ValueError(f"{csv_path}: unknown column(s) {', '.join(unknown)}; "
                                 f"expected {','.join(CSV_COLUMNS)}")
            for line, row in enumerate(reader, start=2):
                clean = {k.strip().lower(): (v or "").strip() for k, v in row.items()
                         if k and k.strip()}
                if not any(clean.values()):  # a blank row (or one of empty cells)
                    continue
                _csv_row(folder, clean, f"{csv_path.name} line {line}", out)
    except UnicodeDecodeError:
        raise ValueError(f"cannot read {csv_path}: it is not UTF-8 text; save it as "
                         "'CSV UTF-8'") from None
    except (OSError, csv.Error) as exc:
        raise ValueError(f"cannot read {csv_path}: {exc}") from None
    listed = {v.path for v in out.videos}
    out.unmatched = [p for p in scan_folder(folder).videos if p not in listed]
    _check(out, f"It is not in {csv_path.name}: add it with role 'reference'")
    out.warnings += case_warnings(out)
    return out


def _delimiter(fh: TextIO) -> str:
    """Commas, or the semicolons (tabs) that spreadsheets write in many locales, read from the
    header line (ties: commas); the file is left at its start. Only the delimiter is guessed:
    quoting stays Excel's, where a doubled quote inside a quoted field is one quote."""
    header = fh.readline()
    fh.seek(0)
    return max(",;\t", key=header.count)


def _csv_row(folder: Path, row: dict[str, str], where: str, out: FolderMapping) -> None:
    path, scene = row.get("path", ""), row.get("scene", "")
    role = _ROLE_WORDS.get(row.get("role", "").lower())
    if not path or not scene:
        out.problems.append(Problem("mapping", where, "path and scene must not be empty"))
        return
    rel = PurePosixPath(path.replace("\\", "/"))
    if rel.is_absolute() or ".." in rel.parts:
        out.problems.append(Problem("mapping", where, f"path {path!r} must be relative to "
                                    "the folder, without '..'"))
        return
    if role is None:
        out.problems.append(Problem("mapping", where, f"role {row.get('role')!r} is not "
                                    "'reference' or 'test'"))
        return
    if (folder / rel).is_dir():
        out.problems.append(Problem("not a video file", where, f"{path} is a folder; init "
                                    "takes video files (encode a frame sequence first)"))
        return
    if not (folder / rel).is_file():
        out.problems.append(Problem("missing file", where, f"{path} does not exist in "
                                    f"{folder}"))
        return
    if role == "reference":
        out.videos.append(MappedVideo(rel, scene, "reference", setting=row.get("setting") or None))
        return
    method, level = row.get("method", ""), row.get("level", "")
    level = re.sub(r"^(\d+)\.0*$", r"\1", level)  # 1.0: a number column saved again
    if not method or not re.fullmatch(r"\d+", level):
        out.problems.append(Problem("mapping", where, "a test video needs a method and a "
                                    f"whole-number level >= 0 (got {method!r}, {level!r})"))
        return
    out.videos.append(MappedVideo(rel, scene, "test", method, int(level),
                                  row.get("setting") or None))


REFERENCE_WORDS = ("reference", "ref", "gt", "groundtruth", "ground_truth", "ground-truth",
                    "original", "orig", "source", "src", "pristine", "clean", "master")


def _reference_candidates(out: FolderMapping, scene: str) -> list[PurePosixPath]:
    """Files left out that look like the missing reference of ``scene``: beside its test
    videos, named like a reference in any case (``Reference.mp4``, ``sponza_GT.mov``)."""
    folders = {v.path.parent for v in out.videos if v.role == "test" and v.scene == scene}
    found = []
    for rel in out.unmatched:
        words = re.split(r"[^a-z0-9]+", rel.stem.lower())
        spaced = rel.stem.lower().replace(scene.lower(), " ")
        if rel.parent in folders and (any(w in REFERENCE_WORDS for w in words) or
                                      spaced.strip(" _-.") in REFERENCE_WORDS):
            found.append(rel)
    return found


def _read_as(video: MappedVideo) -> str:
    if video.role == "reference":
        return f"the reference of {video.scene}"
    return f"method {video.method!r}" + (f", setting {video.setting!r}" if video.setting
                                         else "")


def _duplicate_hint(a: MappedVideo, b: MappedVideo) -> str:
    """Why two files got one id: the same name in two containers (a .mov master and its .mp4
    preview: a literal extension in the patterns takes one set), or what each was read as."""
    if a.path.with_suffix("") == b.path.with_suffix(""):
        return (f" (the same name as {a.path.suffix} and {b.path.suffix}: to take only one, "
                f"end the patterns in a literal extension, e.g. "
                f"--pattern '{{scene}}/{{method}}_L{{level}}{a.path.suffix}')")
    return f" (read as {_read_as(a)} and {_read_as(b)})"


def _unportable(videos: list[MappedVideo]) -> list[Problem]:
    """Folder and file names a participant's download refuses on every system (the study's
    copies keep them): one problem per name, with a file it holds."""
    found: dict[tuple[int, str], Problem] = {}
    for video in videos:
        parts = video.path.parts
        for depth, part in enumerate(parts):
            if (depth, part) in found or (why := portable_part_problem(part)) is None:
                continue
            what = "file" if depth == len(parts) - 1 else "folder"
            found[(depth, part)] = Problem(
                "bad name", str(video.path), f"{what} name {part!r} {why}; every "
                f"participant's download would refuse it: rename the {what}")
    return list(found.values())


def _check(out: FolderMapping, fix: str = "") -> None:
    """Ids that are not valid, used twice, or test videos without a reference (with the
    files left out that look like it, and ``fix``: how to take one)."""
    seen: dict[str, MappedVideo] = {}
    for video in out.videos:
        sid = video.stimulus_id
        if not is_valid_id(sid):
            out.problems.append(Problem(
                "bad id", str(video.path), f"id {sid!r} (from scene/method) may contain only "
                "ASCII letters, digits, '_', '-' and '.'; rename the file or map it in a CSV"))
        if sid in seen:
            out.problems.append(Problem(
                "duplicate id", sid, f"{seen[sid].path} and {video.path} are both {sid}"
                + _duplicate_hint(seen[sid], video)))
        else:
            seen[sid] = video
    out.problems += _unportable(out.videos)
    refs = out.references()
    missing = sorted({v.scene for v in out.videos if v.role == "test"} - set(refs))
    for scene in missing:
        tests = [str(v.path) for v in out.videos if v.role == "test" and v.scene == scene]
        detail = (f"no reference video for scene {scene!r} ({len(tests)} test video(s), e.g. "
                  f"{tests[0]})")
        if candidates := _reference_candidates(out, scene):
            names = " or ".join(c.as_posix() for c in candidates[:3])
            detail += f"; did you mean {names}? {fix}".rstrip()
        elif other := [r for r in refs if r != scene and r.casefold() == scene.casefold()]:
            detail += (f"; {refs[other[0]].path} is the reference of scene {other[0]!r}, which "
                       "differs only in case: rename one so the names match")
        out.problems.append(Problem("missing reference", scene, detail))
