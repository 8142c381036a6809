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
    parser.add_argument("--purge-backups", action="store_true",
                        help="delete the participant's data from the backups in "
                             "server/backups/ too (each keeps a tombstone; the other "
                             "participants' data stay); also for one who withdrew before")


def run(args: argparse.Namespace) -> int:
    from study_server.operations import withdraw

    w = withdraw(args.study, args.participant, args.reason, purge_backups=args.purge_backups)
    if w.tombstone is not None:
        print(f"{args.participant}: {w.tombstone.entries_deleted} uploaded entries deleted; "
              f"tombstone kept ({w.tombstone.withdrawn_at})")
    else:
        print(f"{args.participant}: withdrawn before; only the backups were searched")
    for p in w.deleted_files:
        print(f"  deleted {p}")
    if not w.wal_cleared:
        print("  note: the server was reading; the deleted pages leave its write-ahead log at "
              "its next checkpoint")
    for p in w.backups_purged:
        print(f"  deleted from the backup {p}")
    if w.backups_holding:
        print(f"  {len(w.backups_holding)} backup(s) still hold this participant's data: "
              + ", ".join(str(p) for p in w.backups_holding)
              + f"; 'cgvq-study withdraw {args.study} {args.participant} --purge-backups' "
              "deletes them there")
    print("  pulled copies made before now, and backups kept elsewhere, still hold this "
          "participant's data: delete them too (a pull into the same folder deletes its copy)")
    return 0
