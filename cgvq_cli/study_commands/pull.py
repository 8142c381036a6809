"""``cgvq-study pull URL --admin-token T --out DIR``: every session as the server received it."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

NAME = "pull"
HELP = "download every participant's session file from a study server, as received"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("url", help="the server's address (e.g. https://study.example.org)")
    parser.add_argument("--admin-token", default=None,
                        help="the admin token (default: $CGVQ_ADMIN_TOKEN)")
    parser.add_argument("--out", type=Path, required=True, help="folder for the session files")
    parser.add_argument("--csv", type=Path, default=None, metavar="FILE",
                        help="also write the tidy ratings table (cgvq-ratings CSV)")
    parser.add_argument("--answers", type=Path, default=None, metavar="FILE",
                        help="also write the questionnaire answers (cgvq-answers CSV; vision "
                             "checks beside it as FILE_screenings.csv): personal data, kept "
                             "out of the ratings table")


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from study_app.remote.admin import pull

    token = args.admin_token or os.environ.get("CGVQ_ADMIN_TOKEN", "")
    if not token:
        raise StudyError("give --admin-token or set $CGVQ_ADMIN_TOKEN")
    result = pull(args.url, token, args.out, csv=args.csv, answers=args.answers)
    print(f"study {result.study_id}: {len(result.sessions)} session(s) into {args.out}")
    worst = 0
    for s in result.sessions:
        r = s.report
        state = r.state if r else "?"
        line = (f"  {s.participant}: {r.n_ratings if r else '?'} of {r.n_planned if r else '?'}"
                f" ratings, {state}, version {s.version} ({(s.manifest_sha256 or '')[:12]})")
        if s.n_answers or s.vision:
            line += f"; {s.n_answers} question(s) answered"
            if s.vision:
                line += "; vision: " + ", ".join(f"{t} {o}" for t, o in sorted(s.vision.items()))
        print(line)
        for f in s.flags:
            times = f" (x{f['count']})" if f.get("count", 1) > 1 else ""
            print(f"    FLAG {f['kind']}{times}: {f['message']}")
        if r is not None:
            worst = max(worst, r.exit_code)
            for p in r.problems:
                print(f"    problem: {p.message}")
    if result.not_started:
        print(f"  not started: {', '.join(result.not_started)}")
    if result.withdrawn:
        print(f"  withdrawn (data deleted): {', '.join(result.withdrawn)}")
    if result.withdrew_in_app:
        tables = "; their rows are in no table" if args.csv or args.answers else ""
        print(f"  withdrew in the app: {', '.join(result.withdrew_in_app)} (their session "
              f"files carry the withdrawal and no analysis uses them{tables}); their data "
              "stay on the server until you delete them with 'cgvq-study withdraw STUDY ID' "
              "there")
    for path in result.removed:
        print(f"  deleted {path}: an earlier pull's copy of a participant who has withdrawn")
    for path in result.rewritten:
        print(f"  wrote {path} again: an earlier pull's table, without the participants who "
              "have withdrawn")
    flagged = sum(1 for s in result.sessions if s.flags)
    print(f"{flagged} participant(s) flagged; server listing: {result.listing_path}")
    for sha, path in result.manifests.items():
        n = sum(1 for x in result.sessions if x.manifest_sha256 == sha)
        print(f"manifest of version {sha[:12]}...: {path} ({n} session(s))")
    several = len(result.manifests) > 1
    if several:
        print("  the sessions ran on several versions of the manifest: analyse each version's "
              "sessions with its own manifest (the analysis refuses the others)")
    if result.csv_path is not None:
        print(f"ratings CSV: {result.csv_path} ({result.n_csv_rows} rows"
              + ("; each row names its manifest version, and the analysis keeps the rows of "
                 "the manifest it is given" if several else "") + ")")
    if result.answers_path is not None:
        print(f"answers CSV: {result.answers_path} ({result.n_answer_rows} rows)"
              + (f"; vision checks: {result.screenings_path}" if result.screenings_path else ""))
    return 2 if worst == 2 else 0
