"""Loading, saving and validating manifest files.

``load_manifest`` checks the document's structure (schema, ids, references, path syntax).
``validate_manifest`` goes further on demand: files present, inside the root, readable as
video, checksums matching. ``structure_only=True`` skips everything that needs the videos, so
a template such as ``cgvqd.json`` validates before the dataset is downloaded.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError
from tqdm.auto import tqdm

from .checksums import ChecksumMismatch, sha256_path
from .errors import ManifestError, StimuliError
from .model import STUDY_TEXT_FILES, Manifest
from .paths import check_relative, resolve_inside

log = logging.getLogger(__name__)


@dataclass
class LoadedManifest:
    """A manifest together with where it came from, so paths can be resolved."""

    manifest: Manifest
    source: Path | None
    root: Path
    sha256: str | None = None

    def resolve(self, relative: str, *, field: str = "path") -> Path:
        """Absolute path of a stimulus path, refusing anything that leaves the root."""
        return resolve_inside(self.root, relative, field=field)

    def stimulus_path(self, stimulus_id: str) -> Path:
        stim = self.manifest.stimulus_by_id(stimulus_id)
        return self.resolve(stim.path, field=f"stimulus {stimulus_id}")

    def reference_path(self, ref_id: str) -> Path:
        return self.resolve(self.manifest.reference_by_id(ref_id).path, field=f"reference {ref_id}")

    def text_path(self, name: str) -> Path | None:
        """A study text (``briefing.md``, ``consent.md``) beside the manifest file."""
        return self.source.parent / name if self.source is not None else None


def _format_validation_error(exc: ValidationError, source: str) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(document)"
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{loc}: {msg}")
    return f"invalid manifest {source}: " + "; ".join(parts)


def parse_manifest(data: dict[str, Any], *, source: str = "<manifest>") -> Manifest:
    """Build a :class:`Manifest` from a JSON-like dict; errors name the offending field."""
    if not isinstance(data, dict):
        raise ManifestError(f"invalid manifest {source}: the document must be a JSON object")
    try:
        manifest = Manifest.model_validate(data)
    except ValidationError as exc:
        raise ManifestError(_format_validation_error(exc, source)) from None
    for i, ref in enumerate(manifest.references):
        check_relative(ref.path, field=f"references[{i}].path ({ref.id})")
    for i, cond in enumerate(manifest.conditions):
        check_relative(cond.path, field=f"conditions[{i}].path ({cond.id})")
    return manifest


def load_manifest(path: str | Path, *, root: str | Path | None = None) -> LoadedManifest:
    """Read and structurally validate a manifest file.

    ``root`` overrides the manifest's own ``root`` (for templates whose data lives elsewhere).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise ManifestError(f"manifest not found: {path}") from None
    except OSError as exc:
        raise ManifestError(f"cannot read manifest {path}: {exc.strerror}") from None
    try:
        data = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ManifestError(f"manifest {path} is not valid JSON: {exc}") from None
    manifest = parse_manifest(data, source=str(path))
    if root is not None:
        root_path = Path(root)
    else:
        root_path = Path(manifest.root)
        if not root_path.is_absolute():
            root_path = path.parent / root_path
    import hashlib

    return LoadedManifest(manifest, path, root_path, hashlib.sha256(raw).hexdigest())


def manifest_to_json(manifest: Manifest) -> str:
    """The canonical JSON text of a manifest (stable key order, 2-space indent)."""
    data = manifest.model_dump(mode="json", exclude_none=True)
    return json.dumps(data, indent=2, ensure_ascii=False) + "\n"


def save_manifest(manifest: Manifest, path: str | Path) -> Path:
    """Write the manifest atomically (temporary file + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(manifest_to_json(manifest), encoding="utf-8")
    tmp.replace(path)
    return path


@dataclass
class ValidationReport:
    """What ``validate_manifest`` found. ``ok`` is False when any error was found."""

    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    mismatches: list[ChecksumMismatch] = field(default_factory=list)
    checked_files: int = 0
    structure_only: bool = False

    @property
    def ok(self) -> bool:
        return not self.errors and not self.mismatches

    def raise_for_errors(self) -> None:
        if not self.ok:
            lines = self.errors + [str(m) for m in self.mismatches]
            raise ManifestError(
                f"manifest validation failed ({len(lines)} problem(s)): " + "; ".join(lines)
            )


def validate_manifest(
    loaded: LoadedManifest,
    *,
    structure_only: bool = False,
    verify_checksums: bool = True,
    probe_videos: bool = False,
    progress: bool = False,
    known_sha256: Mapping[Path, str] | None = None,
) -> ValidationReport:
    """Check files against the manifest; never raises for problems it can report.

    Structure (schema, ids, path syntax) was checked at load time. Unless ``structure_only``,
    each referenced file must exist inside the root; with ``verify_checksums`` its sha256 must
    match the recorded one (files without a recorded checksum are listed as warnings); with
    ``probe_videos`` each file must open as a video. ``known_sha256`` (resolved path to
    sha256) holds files the caller hashed moments ago (a download checked in this run); they
    are compared, not read again.
    """
    report = ValidationReport(structure_only=structure_only)
    known = known_sha256 or {}
    manifest = loaded.manifest
    if structure_only:
        return report
    entries: list[tuple[str, str, str | None]] = [
        (str(r.id), r.path, r.sha256) for r in manifest.references
    ] + [(str(c.id), c.path, c.sha256) for c in manifest.conditions]
    if not loaded.root.is_dir():
        report.errors.append(f"root folder {loaded.root} does not exist")
        return report
    _validate_texts(loaded, report, verify_checksums, known)
    for stim_id, rel, expected in tqdm(
        entries, desc="checking stimuli", unit="file", disable=not progress, leave=False
    ):
        try:
            path = loaded.resolve(rel, field=f"{stim_id}.path")
        except ManifestError as exc:
            report.errors.append(str(exc))
            continue
        if not path.exists():
            report.errors.append(f"{stim_id}: file {path} does not exist")
            continue
        report.checked_files += 1
        if verify_checksums:
            if expected is None:
                report.warnings.append(f"{stim_id}: no sha256 recorded in the manifest")
            else:
                try:
                    actual = _sha256(path, known)
                except StimuliError as exc:
                    report.errors.append(f"{stim_id}: {exc}")
                    continue
                if actual != expected:
                    report.mismatches.append(ChecksumMismatch(stim_id, path, expected, actual))
        if probe_videos:
            from .video import probe_video

            try:
                probe_video(path)
            except StimuliError as exc:
                report.errors.append(f"{stim_id}: {exc}")
    return report


def _sha256(path: Path, known: Mapping[Path, str]) -> str:
    """The file's sha256: the caller's when it hashed the file in this run, else read."""
    found = known.get(path.resolve()) if known else None
    return found if found is not None else sha256_path(path)


def _validate_texts(loaded: LoadedManifest, report: ValidationReport, verify: bool,
                    known: Mapping[Path, str]) -> None:
    """The study texts beside the manifest: present when recorded, matching their sha256."""
    if loaded.source is None:
        return
    recorded = loaded.manifest.texts
    for name in STUDY_TEXT_FILES:
        path = loaded.text_path(name)
        expected = recorded.get(name)
        if path is None or not path.is_file():
            if expected is not None:
                report.errors.append(f"{name}: recorded in the manifest but missing beside it")
            continue
        report.checked_files += 1
        if not verify:
            continue
        if expected is None:
            report.warnings.append(f"{name}: no sha256 recorded in the manifest (record it "
                                   "with: python -m stimuli_manifests hash MANIFEST)")
            continue
        actual = _sha256(path, known)
        if actual != expected:
            report.mismatches.append(ChecksumMismatch(name, path, expected, actual))


def fill_checksums(loaded: LoadedManifest, *, progress: bool = False) -> Manifest:
    """Return a copy of the manifest with every sha256 computed from the files on disk."""
    manifest = loaded.manifest.model_copy(deep=True)
    items = list(manifest.references) + list(manifest.conditions)
    for item in tqdm(items, desc="hashing", unit="file", disable=not progress, leave=False):
        path = loaded.resolve(item.path, field=f"{item.id}.path")
        if not path.exists():
            raise ManifestError(f"{item.id}: file {path} does not exist; cannot compute sha256")
        item.sha256 = sha256_path(path)
    texts = {}
    for name in STUDY_TEXT_FILES:
        path = loaded.text_path(name)
        if path is not None and path.is_file():
            texts[name] = sha256_path(path)
    manifest.texts = texts
    return manifest
