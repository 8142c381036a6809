"""``cgvq-study export SESSION_FILE``: the one file a participant sends back."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "export"
HELP = ("pack a session file into one zip to send back, <participant>_<session>.zip in the "
        "current folder (and optionally write the ratings CSV); a damaged file is exported "
        "as it is and exits 2")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", type=Path, help="the session file (<participant>.sqlite)")
    parser.add_argument("--out", type=Path, default=None, metavar="ZIP|DIR",
                        help="zip file or folder to write to (default: the current folder)")
    parser.add_argument("--csv", type=Path, default=None, metavar="OUT",
                        help="also write the tidy ratings CSV to OUT")


def run(args: argparse.Namespace) -> int:
    from session_store import read_session, verify_session, write_ratings_csv
    from session_store.errors import StudyError
    from study_app.export import (
        check_ratings_csv_target,
        export_name,
        export_session,
        export_target,
    )

    if args.session.is_dir():
        found = sorted(args.session.glob("*.sqlite"))
        raise StudyError(
            f"{args.session} is a folder; export takes one session file, e.g. {found[0]}"
            if found else f"{args.session} is a folder and holds no session file (*.sqlite); "
            "give the participant's session file (<participant>.sqlite)")
    if not args.session.exists():
        raise StudyError(f"session file not found: {args.session}")
    report = verify_session(args.session)
    export_target(args.out, export_name(args.session))  # every target checked before writing
    if args.csv is not None:
        if report.withdrawn:
            # A CSV cannot carry the withdrawal, and the analysis would use its rows.
            raise StudyError(f"{args.session}: the participant withdrew from the study, so "
                             "their ratings are not written to a CSV; export without --csv "
                             "(the zip carries the withdrawal)")
        check_ratings_csv_target(args.csv)
    out = export_session(args.session, args.out)
    if args.csv is not None:
        rows = read_session(args.session).ratings
        write_ratings_csv(rows, args.csv)
        print(f"ratings CSV: {args.csv} ({len(rows)} rows)")
    print(f"{out}  ({report.n_ratings} of {report.n_planned} ratings, {report.state.upper()})")
    for problem in report.problems:
        print(f"  problem: {problem}")
    for warning in report.warnings:
        print(f"  warning: {warning}")
    if report.state == "damaged":  # exported anyway; scripts see it by the exit code (2)
        sys.stdout.flush()
        first = report.problems[0].message if report.problems else "damaged"
        raise StudyError(f"{args.session} is damaged ({first}); the zip {out} was written "
                         "anyway: send it to the experimenter as it is")
    return 0
