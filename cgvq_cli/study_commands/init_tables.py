"""What ``cgvq-study init`` prints: the probe table, the problems, and what changed."""

from __future__ import annotations

import shlex
from pathlib import Path

from cgvq_cli.text_table import format_table
from session_store.study_folder import SESSIONS_DIR
from stimuli_manifests.from_folder.mapping import Problem
from study_app.study_init import InitResult


def print_probe_table(result: InitResult, folder: Path) -> None:
    """One row per mapped file: what it is, what it holds, how fast it decodes here."""
    rows = []
    for video in result.mapping.videos:
        probe = result.probes.get(folder.resolve() / video.path)
        info = probe.info if probe else None
        what = "reference" if video.role == "reference" else f"{video.method} L{video.level}"
        if info is None:
            rows.append([video.path, video.stimulus_id, what, "-", "-", "-", "-", "-", "-", "-",
                         (probe.error_kind if probe else "undecodable").upper()])
            continue
        rows.append([video.path, video.stimulus_id, what, f"{info.width}x{info.height}",
                     f"{info.fps:g}", info.frame_count, f"{info.duration:.2f}",
                     f"{info.pix_fmt} {info.bit_depth}-bit", info.codec,
                     f"{probe.decode_fps:.0f}", _mib(probe.size_bytes)])
    print(f"{len(rows)} video(s) in {folder}:")
    print(format_table(["file", "id", "role", "size", "fps", "frames", "s", "pixels", "codec",
                        "decode fps", "MiB"], rows))
    if result.study_probes:
        speeds = [p.decode_fps for p in result.study_probes.values() if p.info is not None]
        if speeds:
            print(f"transcoded copies decode at {min(speeds):.0f}-{max(speeds):.0f} fps here")


def print_warnings(warnings: list[str]) -> None:
    """Warnings, one line per distinct message with the files it applies to (a warning
    about a whole method keeps its subject in front, as ``check`` prints it)."""
    groups: dict[str, list[str]] = {}
    for warning in warnings:
        subject, _, detail = warning.partition(": ")
        if subject.startswith("method "):
            groups.setdefault(warning, [])
            continue
        groups.setdefault(detail or subject, []).append(subject if detail else "")
    for detail, subjects in groups.items():
        subjects = [s for s in subjects if s]
        if len(subjects) > 3:
            who = f"{len(subjects)} files: {', '.join(subjects[:3])}, ..."
        else:
            who = ", ".join(subjects)
        print(f"  warning: {detail}" + (f" ({who})" if who else ""))


def print_problems(problems: list[Problem]) -> None:
    print(f"problems ({len(problems)}):")
    print(format_table(["problem", "file or stimulus", "what to do"],
                       [[p.kind, p.subject, p.detail] for p in problems], max_width=1000))


def print_changes(result: InitResult, out: Path) -> None:
    """The manifest written (or unchanged), and what changed since the last run."""
    manifest, changes = result.manifest, result.changes
    assert manifest is not None and changes is not None
    n_stimuli = len(manifest.stimuli())
    print(f"study {manifest.study_id}: {len(manifest.references)} reference(s), "
          f"{len(manifest.conditions)} test video(s), {n_stimuli} rated stimuli x "
          f"{manifest.protocol.repetitions} repetitions = "
          f"{n_stimuli * manifest.protocol.repetitions} trials")
    for label, ids in (("added", changes.added), ("removed", changes.removed),
                       ("replaced (new file or content)", changes.replaced),
                       ("settings changed", changes.settings),
                       ("mapped anew (scores or ratings under these ids now mean another "
                        "comparison)", changes.remapped)):
        if ids:
            print(f"  {label}: {', '.join(ids)}")
    if (changes.replaced or changes.removed or changes.remapped) and result.manifest_written:
        folder = out / SESSIONS_DIR
        held = sorted(p.name for p in folder.glob("*.sqlite")) if folder.is_dir() else []
        print("  sessions run before this change (a pilot's, say) were run on the previous "
              "manifest: the analysis refuses them, so pilot again"
              + (f"; in {folder}: {', '.join(held)} (move them out)" if held else ""))
    if "display" in changes.settings:
        d = manifest.display
        print(f"  the participant's display now needs at least {d.min_width}x{d.min_height} "
              f"pixels at {d.min_refresh_hz:g} Hz or more")
    seat = manifest.protocol.viewing_distance_cm
    if seat is not None and result.manifest_written:
        print(f"  participants are told to sit about {seat:g} cm from the screen while they "
              "rate (before the trials and after each break)")
    elif seat is None and "protocol" in changes.settings:
        print("  participants are not told where to sit")
    if changes.restored:
        print(f"  copied again (the study's copy was missing or edited): "
              f"{', '.join(changes.restored)}")
    if changes.files_deleted:
        n = len(changes.files_deleted)
        print(f"  deleted {n} cop{'y' if n == 1 else 'ies'} nothing refers to any more")
    if not result.manifest_written:
        print(f"no changes: {out / 'manifest.json'} is up to date"
              + (" (copies restored as listed)" if changes.restored else ""))
    else:
        print(f"wrote {out / 'manifest.json'}; next: cgvq-study check {shlex.quote(str(out))}, "
              f"then cgvq-study preview {shlex.quote(str(out))}")


def _mib(size: int) -> str:
    return f"{size / 2**20:.1f}"
