"""``cgvq-study init FOLDER --out STUDY``: a study folder from a researcher's own videos."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "init"
HELP = ("build a study folder from a folder of videos (reference and test videos per scene): "
        "probe every file, list every problem, copy or transcode, write the manifest")
EPILOG = """\
Files are mapped by two patterns over paths relative to FOLDER (placeholders {scene},
{method}, {level}, {setting}, {ext}); the lowest level is the strongest distortion, higher
levels are milder (1, 2, 3, or sample counts such as 4, 16, 64). Or list the files in a CSV
with the columns path,scene,role,method,level,setting (role: reference or test). Re-running
on a changed folder updates the study and reports what changed; settings edited in
STUDY/manifest.json are kept, and so are the options of the last init (patterns or
--mapping, --transcode; kept in STUDY/init.json) that are not given again. Exit 0 written
(or unchanged), 2 problems found (nothing written) or bad input."""


def register(parser: argparse.ArgumentParser) -> None:
    from stimuli_manifests.from_folder.mapping import (
        DEFAULT_REFERENCE_PATTERN,
        DEFAULT_TEST_PATTERN,
    )
    from stimuli_manifests.lossless import LOSSLESS_CODECS, PLAYER_CODEC

    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("folder", type=Path, help="folder of videos (one subfolder per scene by "
                                                  "default)")
    parser.add_argument("--out", type=Path, required=True, metavar="STUDY",
                        help="the study folder to write (new, or one init made before)")
    parser.add_argument("--pattern", metavar="PATTERN",
                        help=f"path pattern of test videos (default {DEFAULT_TEST_PATTERN})")
    parser.add_argument("--reference-pattern", metavar="PATTERN",
                        help=f"path pattern of references (default {DEFAULT_REFERENCE_PATTERN})")
    parser.add_argument("--mapping", type=Path, metavar="CSV",
                        help="CSV mapping files to path,scene,role,method,level,setting "
                             "(instead of the patterns)")
    parser.add_argument("--study-id", help="the study's id (default: the --out folder's name)")
    parser.add_argument("--transcode", nargs="?", const=PLAYER_CODEC, default=None,
                        choices=tuple(LOSSLESS_CODECS), metavar="CODEC",
                        help="write lossless player-ready copies instead of exact copies "
                             f"(default codec {PLAYER_CODEC}, the fastest to decode; "
                             f"{', '.join(LOSSLESS_CODECS)})")
    parser.add_argument("--no-transcode", action="store_true",
                        help="exact copies, even though the last init into STUDY transcoded")
    parser.add_argument("--min-display", metavar="WxH",
                        help="the participants' minimum screen size in pixels (default: the "
                             "manifest's, else 1920x1080)")
    parser.add_argument("--min-refresh-hz", type=float, metavar="HZ",
                        help="the participants' minimum refresh rate (default: the manifest's, "
                             "else 59)")
    parser.add_argument("--viewing-distance", type=float, metavar="CM",
                        help="ask participants to sit this far from the screen while they "
                             "rate (30-200 cm; told before the trials and after breaks; "
                             "0 removes the instruction; default: the manifest's, else none)")
    parser.add_argument("--force", action="store_true",
                        help="change stimuli even when the study already holds sessions, "
                             "or replace them from another renders folder")


def _display(args: argparse.Namespace) -> tuple[tuple[int, int] | None, float | None]:
    """(minimum screen, minimum refresh rate) given on the command line; None where not
    given, so that a re-run keeps the manifest's value of the other."""
    from session_store.errors import StudyError

    from .run import parse_size

    size = None
    if args.min_display is not None:
        size = parse_size(args.min_display, option="--min-display")
        if size[0] < 1 or size[1] < 1:
            raise StudyError(f"--min-display must be at least 1x1 pixels, got "
                             f"{args.min_display}")
    hz = args.min_refresh_hz
    if hz is not None and not 1 <= hz <= 1000:
        raise StudyError(f"--min-refresh-hz must be between 1 and 1000, got {hz:g}")
    return size, hz


def _viewing_distance(args: argparse.Namespace) -> float | None:
    from session_store.errors import StudyError

    cm = args.viewing_distance
    if cm is not None and cm != 0 and not 30 <= cm <= 200:
        raise StudyError(f"--viewing-distance must be 30 to 200 cm (or 0 to remove the "
                         f"instruction), got {cm:g}")
    return cm


def _with_last_choices(args: argparse.Namespace, patterns_given: bool
                       ) -> tuple[Path | None, str | None, str | None, str | None]:
    """(mapping CSV, test pattern, reference pattern, transcode codec): what is given, and
    for the rest what the last init into STUDY used (said on stdout), so that a re-run with
    no options maps and copies the renders as before."""
    from session_store.errors import StudyError
    from stimuli_manifests.lossless import LOSSLESS_CODECS
    from study_app.init_choices import INIT_FILE, InitChoices, read_choices, resolved_path

    mapping, pattern, ref_pattern, transcode = (args.mapping, args.pattern,
                                                args.reference_pattern, args.transcode)
    last = read_choices(args.out) if args.out.is_dir() else None
    if last is None:
        return mapping, pattern, ref_pattern, transcode
    kept = InitChoices()
    if mapping is None and not patterns_given and last.mapping_csv is not None:
        mapping = resolved_path(args.out, last.mapping_csv)
        kept = InitChoices(mapping_csv=str(mapping))
    elif mapping is None and last.mapping_csv is None:
        kept = InitChoices(None if pattern else last.test_pattern,
                           None if ref_pattern else last.reference_pattern)
        pattern = pattern or last.test_pattern
        ref_pattern = ref_pattern or last.reference_pattern
    if transcode is None and not args.no_transcode and last.transcode is not None:
        if last.transcode not in LOSSLESS_CODECS:
            raise StudyError(f"{args.out / INIT_FILE}: transcode {last.transcode!r} is not one "
                             f"of {', '.join(LOSSLESS_CODECS)}; give --transcode or "
                             "--no-transcode")
        transcode = last.transcode
        kept = InitChoices(kept.test_pattern, kept.reference_pattern, kept.mapping_csv,
                           transcode)
    if kept.options():
        print(f"as the last init into {args.out}: {' '.join(kept.options())} (from "
              f"{args.out / INIT_FILE}; give options to change them)", flush=True)
    return mapping, pattern, ref_pattern, transcode


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from stimuli_manifests.from_folder.mapping import (
        DEFAULT_REFERENCE_PATTERN,
        DEFAULT_TEST_PATTERN,
    )
    from study_app.study_init import InitOptions, init_study

    from .init_tables import print_changes, print_probe_table, print_problems, print_warnings

    given = [f for f, v in (("--pattern", args.pattern),
                            ("--reference-pattern", args.reference_pattern)) if v is not None]
    if args.mapping is not None and given:
        raise StudyError(f"{given[0]} maps files by their names; --mapping lists them in a CSV "
                         "instead: give one or the other")
    if args.transcode is not None and args.no_transcode:
        raise StudyError("--transcode and --no-transcode: give one or the other")
    min_display, min_refresh_hz = _display(args)
    mapping, pattern, reference_pattern, transcode = _with_last_choices(args, bool(given))
    opts = InitOptions(folder=args.folder, out=args.out, mapping_csv=mapping,
                       test_pattern=pattern or DEFAULT_TEST_PATTERN,
                       reference_pattern=reference_pattern or DEFAULT_REFERENCE_PATTERN,
                       study_id=args.study_id, transcode=transcode,
                       min_display=min_display, min_refresh_hz=min_refresh_hz,
                       viewing_distance_cm=_viewing_distance(args), force=args.force,
                       progress=sys.stderr.isatty())  # no bar in the one-line error of a pipe
    result = init_study(opts)
    print_probe_table(result, opts.folder)
    print_warnings(result.warnings)
    if not result.ok:
        print_problems(result.problems)
        if result.suggestion:
            print(f"the names read another way: {result.suggestion}", flush=True)
        print(f"{len(result.problems)} problem(s): nothing was written to {args.out}; fix them "
              "and run init again", flush=True)
        raise StudyError(f"{len(result.problems)} problem(s) (listed on stdout), e.g. "
                         f"{result.problems[0]}; nothing was written to {args.out}"
                         + (f"; {result.suggestion}" if result.suggestion else ""))
    print_changes(result, args.out)
    return 0
