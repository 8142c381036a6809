"""``cgvq-study run STUDY --participant ID``: the participant's session; or, from a study
server, ``cgvq-study run --server URL --participant ID --token T`` (``--invite FILE``): the
study is downloaded first and every change of the session file is uploaded as it happens."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

NAME = "run"
HELP = "run (or resume) a participant's rating session of a study folder"


def parse_size(text: str, *, option: str = "--window-size") -> tuple[int, int]:
    """``1280x1024`` -> (1280, 1024); anything else is a one-line user error."""
    from session_store.errors import StudyError

    m = re.fullmatch(r"\s*(\d{1,6})\s*[xX]\s*(\d{1,6})\s*", text or "")
    if not m:
        raise StudyError(f"{option} expects WIDTHxHEIGHT in pixels (e.g. 1920x1080), "
                         f"got {text!r}")
    return int(m.group(1)), int(m.group(2))


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, nargs="?", default=None,
                        help="study folder (holds manifest.json); not with --server")
    parser.add_argument("--participant", default=None,
                        help="participant id (1-64 letters, digits, -_.)")
    server = parser.add_argument_group("a study served by the experimenter")
    server.add_argument("--server", default=None, metavar="URL",
                        help="the study server's address (from the experimenter)")
    server.add_argument("--token", default=None, help="your token (from the experimenter)")
    server.add_argument("--invite", type=Path, default=None, metavar="FILE",
                        help="the invite file from the experimenter (instead of --server, "
                             "--participant and --token)")
    server.add_argument("--data-dir", type=Path, default=None, metavar="DIR",
                        help="where the study is downloaded and the session file kept "
                             "(default: your user data folder, cgvq-study)")
    parser.add_argument("--windowed", action="store_true", help="run in a window, not full screen")
    parser.add_argument("--skip-preflight", action="store_true",
                        help="run even when pre-flight checks fail (pilots, tests); recorded")
    parser.add_argument("--seed", type=int, default=None,
                        help="trial-order seed (default: derived from study and participant)")
    parser.add_argument("--sessions-dir", type=Path, default=None,
                        help="where session files go (default: STUDY/sessions)")
    parser.add_argument("--practice", type=int, default=2, metavar="N",
                        help="practice trials before a new session, not recorded (default 2)")
    parser.add_argument("--pilot-no-vsync", action="store_true",
                        help="experimenters' pilot/test mode: where the display gives no vsync "
                             "(virtual displays, remote desktops), pace flips on the clock "
                             "instead of stopping at the pre-flight; recorded in the session as "
                             "timing_mode 'paced-pilot' (not valid for participant data)")
    parser.add_argument("--no-vsync", action="store_true",
                        help="pace flips on the clock even when vsync works (implies "
                             "--pilot-no-vsync)")
    parser.add_argument("--refresh-hz", type=float, default=None,
                        help="pacing rate of the pilot mode without vsync (default 60; needs "
                             "--pilot-no-vsync or --no-vsync; with vsync the rate is measured)")
    parser.add_argument("--max-dropped-frames", type=int, default=10, metavar="N",
                        help="re-queue a trial at the end once when more refreshes passed "
                             "without a new frame (a 1 s freeze at 60 Hz: 59; default 10; -1 "
                             "never re-queues)")
    parser.add_argument("--break-every", type=int, default=40, metavar="N",
                        help="offer a break every N trials (default 40; 0 never), except when "
                             "fewer than N/4 are left")
    parser.add_argument("--window-size", default=None, metavar="WxH",
                        help="run in a window of this size (at least 800x600)")
    parser.add_argument("--screenshots", type=Path, default=None, metavar="DIR",
                        help="save a PNG of the first frame of each screen into DIR")


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from session_store.study_folder import load_study
    from study_app.app import RunOptions, run_study

    served = args.server is not None or args.invite is not None or args.token is not None
    if served and args.study is not None:
        raise StudyError("give either a study folder or --server/--invite, not both")
    if not served:
        if args.study is None:
            raise StudyError("give the study folder (cgvq-study run STUDY --participant ID), "
                             "or --server, --participant and --token from the experimenter")
        if args.participant is None:
            raise StudyError("give --participant ID (the id the experimenter gave you)")
        if args.data_dir is not None:
            raise StudyError("--data-dir is where a study downloaded from a server is kept; a "
                             "local study folder keeps its sessions in --sessions-dir")
    invite = None
    if served:
        from study_app.remote.participant import check_invite_args

        invite = check_invite_args(args.server, args.participant, args.token, args.invite)
        args.participant = invite.participant
    opts = RunOptions(
        participant=args.participant, windowed=args.windowed,
        skip_preflight=args.skip_preflight, seed=args.seed, sessions_dir=args.sessions_dir,
        practice=args.practice, refresh_hz=args.refresh_hz,
        max_dropped_frames=args.max_dropped_frames, break_every=args.break_every,
        window_size=parse_size(args.window_size) if args.window_size is not None else None,
        screenshots=args.screenshots, force_pacer=args.no_vsync,
        pilot_no_vsync=args.pilot_no_vsync,
    )
    opts.validate()
    if invite is not None:
        return _run_served(invite, args, opts)
    study = load_study(args.study)
    study.session_path(opts.participant, opts.sessions_dir)  # id and folder, before anything
    outcome = run_study(study, opts)
    return _report(outcome)


FINISHED_FLUSH_S = 60.0
"""How long a start of a finished session waits to send what had not arrived."""
AFTER_END_SCREEN_S = 2.0
"""The end screen already waited for the uploads and said what arrived: one short last try
after it closes, not a second long wait with no window."""


def _run_served(invite, args: argparse.Namespace, opts) -> int:
    """Download, run with the uploader following the session file, report what arrived."""
    from session_store import read_session
    from session_store.study_folder import load_study
    from study_app.app import run_study
    from study_app.remote.http import ServerClient
    from study_app.remote.participant import (
        FLUSH_AT_END_S,
        fetch_study,
        request_block,
        start_uploader,
        upload_report,
    )
    from study_app.remote.uploader import WITHDRAWN

    remote = fetch_study(invite, args.data_dir)
    study = load_study(remote.folder)
    if opts.sessions_dir is None:
        opts.sessions_dir = remote.sessions_dir
    opts.files_from_server = True
    opts.files_verified = remote.verified_sha256
    path = study.session_path(opts.participant, opts.sessions_dir)
    uploader = start_uploader(invite, path)
    try:
        if path.exists():
            info = read_session(path).info
            if info.finished_at is not None:  # nothing to run: send what is left
                print(f"Your session is finished; sending what has not reached the study "
                      f"server yet (at most {FINISHED_FLUSH_S:.0f} s)...", flush=True)
                status = uploader.flush(FINISHED_FLUSH_S)
                print(f"Your session is finished ({path}). {status.describe()}")
                return 0 if status.all_arrived else 1
        reported: list[bool] = []  # the end screen waited for the uploads and said so

        def report() -> tuple[bool, str]:
            reported.append(True)
            return upload_report(uploader)

        opts.upload_report = report
        opts.on_commit = uploader.notify
        opts.ended_by_server = lambda: WITHDRAWN if uploader.status.withdrawn else None
        client = ServerClient(invite.server, invite.token)
        opts.next_block = lambda sid, k, last: request_block(client, invite.participant,
                                                             uploader, sid, k, last)
        outcome = run_study(study, opts)
        wait = (0.0 if not path.exists() else
                AFTER_END_SCREEN_S if reported else FLUSH_AT_END_S)  # never wait twice
        if wait > AFTER_END_SCREEN_S and not uploader.status.all_arrived and \
                uploader.status.state != "refused":
            print(f"Sending your last answers to the study server (at most "
                  f"{FLUSH_AT_END_S:.0f} s)...", flush=True)
        status = uploader.flush(wait)
    finally:
        uploader.stop()
    return _report(outcome, status if path.exists() else None)


def _report(outcome, upload=None) -> int:
    """Print how the run ended; ``upload`` (an UploadStatus) with a study server."""
    if upload is not None and upload.withdrawn:
        print(f"Session ended: {upload.describe()}")
        return 0
    if upload is not None and outcome.status in ("finished", "withdrawn", "quit"):
        what = {"finished": f"Session finished: {outcome.answered} trials.",
                "withdrawn": f"The participant withdrew after {outcome.answered} of "
                             f"{outcome.total} trials.",
                "quit": f"Session saved ({outcome.answered} of {outcome.total} trials "
                        "answered); run the same command again to continue."}[outcome.status]
        print(f"{what} {upload.describe()}" + (
            "" if upload.all_arrived else f" Your session file: {outcome.session_path}"))
        return 0
    if outcome.status == "declined":
        print("Consent declined: nothing was recorded.")
        return 1
    if outcome.status == "closed" and outcome.session_path is not None:
        print(f"Closed before the session continued: nothing new was recorded in "
              f"{outcome.session_path}; run the same command again to continue.")
        return 1
    if outcome.status == "closed":
        print("Closed before the study started: nothing was recorded.")
        return 1
    if outcome.status == "quit":
        print(f"Session saved ({outcome.answered} of {outcome.total} trials answered) in "
              f"{outcome.session_path}; run the same command again to continue.")
        return 0
    if outcome.status == "screened-out":
        check = {"acuity": "sharpness and contrast"}.get(outcome.screened_by, "colour-vision")
        print(f"The session ended after the {check} check (the study's on_fail: end); "
              f"send this file back: {outcome.session_path}")
        return 0
    if outcome.status == "ended":
        print(f"The study server ended the session after {outcome.answered} trials; there is "
              "nothing more to do or to send.")
        return 0
    if outcome.status == "withdrawn":
        print(f"The participant withdrew after {outcome.answered} of {outcome.total} trials; "
              f"the session is marked withdrawn. Send this file back: {outcome.session_path}")
        return 0
    print(f"Session finished: {outcome.answered} trials. Send this file back: "
          f"{outcome.session_path}")
    return 0
