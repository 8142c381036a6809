"""``cgvq-study preview STUDY``: watch the study as a participant will, nothing recorded."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "preview"
HELP = ("the experimenter's pilot: the participant's player, blank, slider and timing on this "
        "computer, with nothing recorded; prints the dropped frames per stimulus")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, help="study folder (holds manifest.json)")
    parser.add_argument("--stimulus", default=None, metavar="ID",
                        help="preview this stimulus only (default: every stimulus once, hidden "
                             "references included, in a participant-like order)")
    parser.add_argument("--timing-overlay", action="store_true",
                        help="show the frame interval, the dropped frames so far and the "
                             "refresh rate beside the video")
    parser.add_argument("--windowed", action="store_true", help="in a window, not full screen")
    parser.add_argument("--window-size", default=None, metavar="WxH",
                        help="window size in pixels (implies --windowed; at least 800x600)")
    parser.add_argument("--pilot-no-vsync", action="store_true",
                        help="accepted as in run; a preview always paces flips on the clock "
                             "where the display gives no vsync, and says so")
    parser.add_argument("--no-vsync", action="store_true",
                        help="pace flips on the clock even when vsync works")
    parser.add_argument("--refresh-hz", type=float, default=None,
                        help="pacing rate without vsync (default 60; with vsync the rate is "
                             "measured)")
    parser.add_argument("--screenshots", type=Path, default=None, metavar="DIR",
                        help="save each screen once as a PNG (outside the study folder)")


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from session_store.study_folder import load_study
    from study_app.preview import PreviewOptions, preview_trials, run_preview

    from .run import parse_size

    study = load_study(args.study)
    if args.screenshots is not None and args.screenshots.resolve().is_relative_to(
            study.folder.resolve()):
        raise StudyError("--screenshots must be outside the study folder (a preview writes "
                         "nothing into it)")
    opts = PreviewOptions(
        stimulus=args.stimulus, windowed=args.windowed or args.window_size is not None,
        window_size=parse_size(args.window_size) if args.window_size else None,
        refresh_hz=args.refresh_hz, force_pacer=args.no_vsync,
        pilot_no_vsync=args.pilot_no_vsync, timing_overlay=args.timing_overlay,
        screenshots=args.screenshots)
    opts.validate()
    preview_trials(study, args.stimulus)  # an unknown --stimulus fails before any window
    result = run_preview(study, opts)
    print(f"preview of study {study.manifest.study_id} (nothing recorded):")
    for line in result.lines():
        print(f"  {line}")
    if result.failure is not None:  # the summary so far is on stdout
        sys.stdout.flush()
        raise StudyError(f"the preview stopped: {result.failure}; run 'cgvq-study check'")
    return 0
