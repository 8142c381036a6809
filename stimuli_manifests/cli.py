"""``python -m stimuli_manifests``: validate, summarise and hash manifests from the shell."""

from __future__ import annotations

import argparse
import logging
import sys
from collections import Counter

from .errors import StimuliError
from .manifest_io import fill_checksums, load_manifest, save_manifest, validate_manifest


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m stimuli_manifests", description="Validate and summarise stimulus manifests."
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    val = sub.add_parser(
        "validate", help="check a manifest (and its files unless --structure-only)"
    )
    val.add_argument("manifest")
    val.add_argument("--root", help="dataset root to use instead of the manifest's own")
    val.add_argument(
        "--structure-only", action="store_true", help="check the document only, not the files"
    )
    val.add_argument("--probe", action="store_true", help="also open every file as a video")
    val.add_argument("--no-checksums", action="store_true", help="skip sha256 verification")
    hsh = sub.add_parser("hash", help="compute every sha256 and write them into the manifest")
    hsh.add_argument("manifest")
    hsh.add_argument("--root")
    return parser


def summarise(loaded) -> str:
    m = loaded.manifest
    methods = Counter(c.method for c in m.conditions)
    lines = [
        f"study {m.study_id}: {len(m.references)} references, {len(m.conditions)} conditions, "
        f"{len(m.stimuli())} rated stimuli x {m.protocol.repetitions} repetitions "
        f"= {len(m.stimuli()) * m.protocol.repetitions} trials",
        f"root: {loaded.root}",
        f"scale: {m.scale.min:g}..{m.scale.max:g} ("
        + ", ".join(f"{lab.position:g} {lab.text}" for lab in m.scale.labels)
        + ")",
    ]
    for method, n in methods.items():
        levels = sorted({c.level for c in m.conditions if c.method == method})
        scenes = sorted({m.scene_of(c.reference) for c in m.conditions if c.method == method})
        lines.append(f"  {method}: {n} videos, levels {levels}, scenes {', '.join(scenes)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    try:
        loaded = load_manifest(args.manifest, root=args.root)
        if args.command == "hash":
            path = save_manifest(fill_checksums(loaded, progress=True), args.manifest)
            print(f"wrote checksums into {path}")
            return 0
        print(summarise(loaded))
        report = validate_manifest(
            loaded,
            structure_only=args.structure_only,
            verify_checksums=not args.no_checksums,
            probe_videos=args.probe,
            progress=True,
        )
    except StimuliError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for warning in report.warnings:
        print(f"warning: {warning}")
    for problem in report.errors + [str(m) for m in report.mismatches]:
        print(f"problem: {problem}")
    if report.ok:
        what = "structure" if report.structure_only else f"{report.checked_files} files"
        print(f"OK: {what} valid")
        return 0
    return 1


if __name__ == "__main__":
    sys.exit(main())
