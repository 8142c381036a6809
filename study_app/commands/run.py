"""``cgvq-study run STUDY --participant ID``: the participant's session."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "run"
HELP = "run (or resume) a participant's rating session of a study folder"


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    return w, h


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, help="study folder (holds manifest.json)")
    parser.add_argument("--participant", required=True,
                        help="participant id (letters, digits, -_.)")
    parser.add_argument("--windowed", action="store_true", help="run in a window, not full screen")
    parser.add_argument("--skip-preflight", action="store_true",
                        help="run even when pre-flight checks fail (pilots, tests); recorded")
    parser.add_argument("--seed", type=int, default=None,
                        help="trial-order seed (default: derived from study and participant)")
    parser.add_argument("--sessions-dir", type=Path, default=None,
                        help="where session files go (default: STUDY/sessions)")
    parser.add_argument("--practice", type=int, default=2, metavar="N",
                        help="practice trials before a new session, not recorded (default 2)")
    parser.add_argument("--refresh-hz", type=float, default=None,
                        help="refresh rate to pace at when vsync is absent (default: measured, "
                             "or 60 without vsync)")
    parser.add_argument("--max-dropped-frames", type=int, default=10, metavar="N",
                        help="re-queue a trial at the end once when more frames dropped "
                             "(default 10; -1 never re-queues)")
    parser.add_argument("--break-every", type=int, default=40, metavar="N",
                        help="offer a break every N trials (default 40; 0 never)")
    parser.add_argument("--window-size", type=_size, default=None, metavar="WxH",
                        help="window size with --windowed")
    parser.add_argument("--screenshots", type=Path, default=None, metavar="DIR",
                        help="save a PNG of the first frame of each screen into DIR")
    parser.add_argument("--no-vsync", action="store_true",
                        help="pace flips with the monotonic clock even when vsync is available")


def run(args: argparse.Namespace) -> int:
    from ..app import RunOptions, run_study
    from ..study import load_study

    study = load_study(args.study)
    outcome = run_study(study, RunOptions(
        participant=args.participant, windowed=args.windowed,
        skip_preflight=args.skip_preflight, seed=args.seed, sessions_dir=args.sessions_dir,
        practice=args.practice, refresh_hz=args.refresh_hz,
        max_dropped_frames=args.max_dropped_frames, break_every=args.break_every,
        window_size=args.window_size, screenshots=args.screenshots, force_pacer=args.no_vsync,
    ))
    if outcome.status == "declined":
        print("Consent declined: nothing was recorded.")
        return 1
    if outcome.status == "quit":
        print(f"Session saved ({outcome.answered} of {outcome.total} trials answered) in "
              f"{outcome.session_path}; run the same command again to continue.")
        return 0
    print(f"Session finished: {outcome.answered} trials. Send this file back: "
          f"{outcome.session_path}")
    return 0
