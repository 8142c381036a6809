"""``cgvq-study verify FILE...``: schema, hash chain and completeness of returned files; for an
exported zip also every member against SHA256SUMS and the ratings CSV against the session."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from session_store import VerifyReport

NAME = "verify"
HELP = ("check returned session files, exported zips or folders of them (exit 0 all intact "
        "and complete, 1 some incomplete or withdrawn (in the app, or on the server by the "
        "pull listing beside them), 2 some damaged or NOT CHECKED (a path "
        "that holds no session file): a zip is damaged when a member differs from SHA256SUMS, "
        "is missing or unlisted, or its ratings CSV does not match the session file, which "
        "stays the authority)")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", type=Path, nargs="+", metavar="PATH",
                        help="session file (.sqlite), exported .zip, or a folder of them")


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from session_store.pull_listing import server_withdrawals
    from study_app.export import verify_many

    reports = verify_many(args.paths)
    listed: dict[str, dict] = {}  # study id -> the pull listings' withdrawals of that study
    deleted_copies = 0
    for report in reports:
        info = report.info
        who = f"participant {info.participant}, study {info.study_id}" if info else "unknown"
        if not report.checked:  # a missing path or an empty folder: not a damaged file
            print(f"{report.path}: NOT CHECKED, {report.problems[0].message}")
            continue
        if report.state == "damaged":
            print(f"{report.path}: DAMAGED ({who}); {len(report.problems)} problem(s):")
        elif report.state == "complete":
            print(f"{report.path}: intact and complete ({who}): {report.n_ratings} ratings")
        else:
            status = ("withdrawn by the participant" if report.withdrawn else
                      "session finished" if report.finished else "session open")
            print(f"{report.path}: intact but {report.state.upper()} ({who}): "
                  f"{report.n_ratings} of {report.n_planned} ratings, {status}")
        timing = str((info.settings or {}).get("timing_mode") or "") if info else ""
        if "paced" in timing:
            print(f"  a pilot: paced on the clock without vsync (timing mode {timing}); the "
                  "analysis leaves it out beside participants' sessions")
        for problem in report.problems:
            print(f"  {problem.message if problem.path == report.path else problem}")
        for warning in report.warnings:
            print(f"  warning: {warning}")
        if info is not None and report.checked:
            if info.study_id not in listed:
                listed[info.study_id] = server_withdrawals(args.paths, info.study_id)
            gone = listed[info.study_id].get(info.participant)
            if gone is not None:
                deleted_copies += 1
                print(f"  WITHDRAWN ON THE SERVER: {gone.words()}; this copy must not be "
                      "used: delete it (the analysis refuses it)")
    for line in _copies(reports):
        print(line)
    if len(reports) > 1:
        states = [r.state for r in reports]
        counts = {s: states.count(s)
                  for s in ("complete", "incomplete", "withdrawn", "damaged", "not checked")}
        noun = "session files" if "not checked" not in states else "inputs"
        print(f"{len(reports)} {noun}: " + ", ".join(f"{n} {s}" for s, n in counts.items()
                                                      if n))
    code = max((r.exit_code for r in reports), default=2)
    if deleted_copies:
        code = max(code, 1)
    if code == 2:  # the verdict stays on stdout; the failure gets its one line on stderr
        sys.stdout.flush()
        raise StudyError(_failure_line(reports))
    return code


def _copies(reports: list[VerifyReport]) -> list[str]:
    """Files that are one session (a sent file, its export zip, a pulled copy): said once,
    so the counts below are not read as that many participants."""
    by_session: dict[str, list[VerifyReport]] = {}
    for r in reports:
        if r.info is not None and r.checked:
            by_session.setdefault(r.info.session_id, []).append(r)
    return [f"{len(same)} files are copies of one session ({same[0].info.session_id[:12]}..., "
            f"participant {same[0].info.participant}): the analysis uses the copy with the "
            f"most ratings ({', '.join(str(r.path) for r in same)})"
            for same in by_session.values() if len(same) > 1]


def _failure_line(reports: list[VerifyReport]) -> str:
    """One line for stderr: the first damaged or unusable input and how many there were."""
    failed = [r for r in reports if r.exit_code == 2]
    if not failed:
        return "no session file was given (see the report on stdout)"
    first = failed[0]
    problem = first.problems[0].message if first.problems else "damaged"
    what = problem if problem.startswith(str(first.path)) else f"{first.path}: {problem}"
    if len(reports) > 1:
        kind = ("hold no session file" if not any(r.checked for r in failed)
                else "are damaged or unreadable")
        return (f"{len(failed)} of {len(reports)} inputs {kind}, e.g. {what} (see the report "
                "on stdout)")
    return f"{what} (see the report on stdout)"
