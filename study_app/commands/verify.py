"""``cgvq-study verify FILE``: schema, hash chain and completeness of a returned file."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "verify"
HELP = ("check a returned session file or export zip (exit 0 intact and complete, "
        "1 incomplete, 2 damaged)")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", type=Path, help="session file (.sqlite) or exported .zip")


def run(args: argparse.Namespace) -> int:
    from ..export import verify_file

    report = verify_file(args.session)
    info = report.info
    who = f"participant {info.participant}, study {info.study_id}" if info else "unknown"
    if not report.intact:
        print(f"{args.session}: DAMAGED ({who}); {len(report.problems)} problem(s):")
    elif not report.complete:
        print(f"{args.session}: intact but INCOMPLETE ({who}): {report.n_ratings} of "
              f"{report.n_planned} ratings, session {'finished' if report.finished else 'open'}")
    else:
        print(f"{args.session}: intact and complete ({who}): {report.n_ratings} ratings")
    for problem in report.problems:
        print(f"  {problem}")
    return report.exit_code
