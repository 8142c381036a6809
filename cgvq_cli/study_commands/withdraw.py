"""``cgvq-study withdraw STUDY ID``: delete a participant's data, keep a tombstone."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "withdraw"
HELP = ("delete a participant's rows and files on the server side and keep a tombstone "
        "without personal data")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, help="study folder")
    parser.add_argument("participant", help="participant id")
    parser.add_argument("--reason", default="withdrawn on request",
                        help="kept in the tombstone (no personal data, please)")


def run(args: argparse.Namespace) -> int:
    from study_server.operations import withdraw

    w = withdraw(args.study, args.participant, args.reason)
    print(f"{args.participant}: {w.tombstone.entries_deleted} uploaded entries deleted; "
          f"tombstone kept ({w.tombstone.withdrawn_at})")
    for p in w.deleted_files:
        print(f"  deleted {p}")
    if not w.wal_cleared:
        print("  note: the server was reading; the deleted pages leave its write-ahead log at "
              "its next checkpoint")
    print("  pulled copies and backups made before now still hold this participant's data: "
          "delete them too")
    return 0
