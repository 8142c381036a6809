"""Turning mapped, probed videos into a study folder's files and its manifest.

Videos are copied (or transcoded) under ``STUDY/videos/`` keeping the folder's layout, and
each manifest entry records where it came from (``metadata.source``: path, sha256, codec of a
transcode). A re-run compares the new entries with the manifest already there, copies or
transcodes only what changed, removes the copies nothing refers to any more, and keeps every
setting the experimenter edited (scale, protocol, display, texts, titles).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

from tqdm import tqdm

from ..checksums import sha256_file
from ..lossless import LosslessCodec, codec_spec
from ..model import Condition, DisplayRequirements, Manifest, Protocol, Reference
from ..video import VideoSource, write_video
from .mapping import MappedVideo, Problem
from .probe import ProbedVideo

VIDEOS_DIR = "videos"


@dataclass(frozen=True)
class Placement:
    """Where one mapped video goes in the study, and how it gets there."""

    video: MappedVideo
    source: ProbedVideo
    study_path: PurePosixPath
    codec: LosslessCodec | None  # None: an exact copy

    def source_record(self) -> dict[str, Any]:
        record: dict[str, Any] = {"path": self.video.path.as_posix(),
                                  "sha256": self.source.sha256}
        if self.codec is not None:
            record["transcoded"] = self.codec
        return record


@dataclass
class StudyChanges:
    """What a (re-)run changed in the study folder, for the experimenter to read."""

    added: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    replaced: list[str] = field(default_factory=list)
    settings: list[str] = field(default_factory=list)
    remapped: list[str] = field(default_factory=list)
    """Ids kept whose reference, method, level or setting changed, with the change in words:
    scores or ratings keyed by such an id now refer to another comparison."""
    files_written: list[str] = field(default_factory=list)
    """Ids whose copy was written (new, replaced, or missing or edited in the study)."""
    files_deleted: list[str] = field(default_factory=list)

    @property
    def restored(self) -> list[str]:
        """Ids whose copy was written again although their source did not change: the copy
        in the study was missing or no longer had its checksum."""
        return [i for i in self.files_written if i not in {*self.added, *self.replaced}]

    @property
    def stimuli_changed(self) -> bool:
        return bool(self.added or self.removed or self.replaced)

    @property
    def any(self) -> bool:
        return self.stimuli_changed or bool(self.settings or self.files_deleted)


def place(videos: list[MappedVideo], probes: dict[Path, ProbedVideo], folder: Path,
          codec: LosslessCodec | None) -> list[Placement]:
    """Study paths for every video: ``videos/<its path in the folder>`` (suffix of the
    transcode codec when transcoding); sorted by scene, references first, method, level."""
    out = []
    for video in videos:
        rel = PurePosixPath(VIDEOS_DIR) / video.path
        if codec is not None:
            rel = rel.with_suffix(codec_spec(codec).suffix)
        out.append(Placement(video, probes[folder / video.path], rel, codec))
    out.sort(key=lambda p: (p.video.scene, p.video.role != "reference", p.video.method or "",
                            p.video.level or 0))
    return out


def shared_paths(placements: list[Placement]) -> list[Problem]:
    """Stimuli that would land on one file of the study: a transcode gives ``x.mkv`` and
    ``x.mp4`` the same name, and names that differ only in case are one file on the
    participants' macOS and Windows disks. One would overwrite the other."""
    first: dict[str, Placement] = {}
    problems = []
    for pl in placements:
        key = pl.study_path.as_posix().casefold()
        if key in first:
            other = first[key]
            problems.append(Problem(
                "shared file", str(pl.video.path),
                f"would be stored as {pl.study_path}, the same file as {other.video.path} "
                f"({other.study_path}){' once transcoded' if pl.codec else ''}; rename one of "
                "them"))
        else:
            first[key] = pl
    return problems


def _recorded_sources(manifest: Manifest | None) -> dict[str, tuple[dict[str, Any], str, str]]:
    """Stimulus id -> (metadata.source, study path, sha256) of an existing manifest."""
    if manifest is None:
        return {}
    entries: list[Reference | Condition] = [*manifest.references, *manifest.conditions]
    return {str(e.id): (e.metadata.get("source", {}), e.path, e.sha256 or "") for e in entries}


def materialise(placements: list[Placement], study: Path, previous: Manifest | None, *,
                progress: bool = False) -> tuple[dict[str, str], list[str]]:
    """Copy or transcode what is not already in the study; returns id -> sha256 of the file
    in the study, and the ids written. A file is kept when the previous manifest recorded the
    same source, path and codec and the file there still has the recorded checksum."""
    recorded = _recorded_sources(previous)
    shas: dict[str, str] = {}
    written: list[str] = []
    bar = tqdm(placements, desc="copying videos", unit="video", disable=not progress)
    for pl in bar:
        sid = pl.video.stimulus_id
        dest = study / pl.study_path
        old = recorded.get(sid)
        if (old is not None and old[0] == pl.source_record() and old[1] == pl.study_path.as_posix()
                and dest.is_file() and sha256_file(dest) == old[2]):
            shas[sid] = old[2]
            continue
        dest.parent.mkdir(parents=True, exist_ok=True)
        if pl.codec is None:
            tmp = dest.with_name(dest.name + ".part")
            shutil.copyfile(pl.source.path, tmp)
            tmp.replace(dest)
        else:
            source = VideoSource(pl.source.path, on_conversion="quiet")  # init warned of it
            write_video(dest, source.frames(), source.info.fps, codec=pl.codec)
        shas[sid] = sha256_file(dest)
        written.append(sid)
    return shas, written


def build_manifest(placements: list[Placement], shas: dict[str, str], *, study_id: str,
                   previous: Manifest | None, display: DisplayRequirements | None,
                   protocol: Protocol | None = None) -> Manifest:
    """The manifest of the placed videos; settings come from ``previous`` when there is one,
    ``display`` and ``protocol`` override the display requirements and the protocol."""
    refs, conds = [], []
    for pl in placements:
        v, sid = pl.video, pl.video.stimulus_id
        meta = {"source": pl.source_record()}
        if v.role == "reference":
            info = pl.source.info
            assert info is not None  # placements are made only from decodable videos
            refs.append(Reference(id=sid, path=pl.study_path.as_posix(), sha256=shas[sid],
                                  scene=v.scene, fps=round(info.fps, 6), width=info.width,
                                  height=info.height, frames=info.frame_count, metadata=meta))
        else:
            conds.append(Condition(id=sid, reference=v.scene, path=pl.study_path.as_posix(),
                                   method=str(v.method), level=int(v.level or 0),
                                   setting=v.setting, sha256=shas[sid], metadata=meta))
    if previous is None:
        settings: dict[str, Any] = {"study_id": study_id}
    else:
        settings = previous.model_dump(exclude={"references", "conditions", "format"})
        settings["study_id"] = study_id
    if display is not None:
        settings["display"] = display
    if protocol is not None:
        settings["protocol"] = protocol
    return Manifest(**settings, references=refs, conditions=conds)


def compare(previous: Manifest | None, new: Manifest) -> StudyChanges:
    """Stimuli added, removed or replaced (another file or content), and changed settings."""
    changes = StudyChanges()
    old = {sid: (path, sha) for sid, (_, path, sha) in _recorded_sources(previous).items()}
    now = {sid: (path, sha) for sid, (_, path, sha) in _recorded_sources(new).items()}
    changes.added = sorted(set(now) - set(old))
    changes.removed = sorted(set(old) - set(now))
    changes.replaced = sorted(sid for sid in set(old) & set(now) if old[sid] != now[sid])
    changes.remapped = _remapped(previous, new)
    if previous is not None:
        before = previous.model_dump(exclude={"references", "conditions"})
        after = new.model_dump(exclude={"references", "conditions"})
        changes.settings = sorted(k for k in after if before.get(k) != after[k])
    return changes


_MAPPED_FIELDS = ("reference", "method", "level", "setting")


def _remapped(previous: Manifest | None, new: Manifest) -> list[str]:
    """``id (reference a -> b, method x -> y)`` for each test stimulus kept under its id whose
    mapping changed (a scene's reference exported after a first run split its names)."""
    if previous is None:
        return []
    before = {c.id: c for c in previous.conditions}
    out = []
    for cond in sorted(new.conditions, key=lambda c: c.id):
        old = before.get(cond.id)
        if old is None:
            continue
        diffs = [f"{name} {getattr(old, name)} -> {getattr(cond, name)}"
                 for name in _MAPPED_FIELDS if getattr(old, name) != getattr(cond, name)]
        if diffs:
            out.append(f"{cond.id} ({', '.join(diffs)})")
    return out


def delete_stale(previous: Manifest | None, new: Manifest, study: Path) -> list[str]:
    """Remove copies the previous manifest listed under ``videos/`` and the new one does not."""
    if previous is None:
        return []
    keep = {e.path for e in [*new.references, *new.conditions]}
    gone = []
    for entry in [*previous.references, *previous.conditions]:
        rel = PurePosixPath(entry.path)
        if entry.path in keep or not rel.parts or rel.parts[0] != VIDEOS_DIR or ".." in rel.parts:
            continue
        path = study / rel
        if path.is_file():
            path.unlink()
            gone.append(entry.path)
            for folder in path.parents:  # and the folders that held only it
                if folder == study / VIDEOS_DIR or not folder.is_relative_to(study):
                    break
                try:
                    folder.rmdir()
                except OSError:  # not empty
                    break
    return gone
