"""``cgvq-study verify FILE...``: schema, hash chain and completeness of returned files; for an
exported zip also every member against SHA256SUMS and the ratings CSV against the session."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "verify"
HELP = ("check returned session files, exported zips or folders of them (exit 0 all intact "
        "and complete, 1 some incomplete or withdrawn, 2 some damaged: a zip is damaged when "
        "a member differs from SHA256SUMS, is missing or unlisted, or its ratings CSV does not "
        "match the session file, which stays the authority)")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", type=Path, nargs="+", metavar="PATH",
                        help="session file (.sqlite), exported .zip, or a folder of them")


def run(args: argparse.Namespace) -> int:
    from study_app.export import verify_many

    reports = verify_many(args.paths)
    for report in reports:
        info = report.info
        who = f"participant {info.participant}, study {info.study_id}" if info else "unknown"
        if report.state == "damaged":
            print(f"{report.path}: DAMAGED ({who}); {len(report.problems)} problem(s):")
        elif report.state == "complete":
            print(f"{report.path}: intact and complete ({who}): {report.n_ratings} ratings")
        else:
            status = ("withdrawn by the participant" if report.withdrawn else
                      "session finished" if report.finished else "session open")
            print(f"{report.path}: intact but {report.state.upper()} ({who}): "
                  f"{report.n_ratings} of {report.n_planned} ratings, {status}")
        for problem in report.problems:
            print(f"  {problem.message if problem.path == report.path else problem}")
        for warning in report.warnings:
            print(f"  warning: {warning}")
    if len(reports) > 1:
        counts = {s: sum(r.state == s for r in reports)
                  for s in ("complete", "incomplete", "withdrawn", "damaged")}
        print(f"{len(reports)} session files: " + ", ".join(f"{n} {s}" for s, n in
                                                             counts.items() if n))
    return max((r.exit_code for r in reports), default=2)
