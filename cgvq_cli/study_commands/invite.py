"""``cgvq-study invite STUDY --n N --out invites.csv``: participant ids and tokens."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "invite"
HELP = ("create participant ids with random tokens (the server keeps only their hashes) and "
        "write them with a ready-to-send command line to a CSV")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, help="study folder (holds manifest.json)")
    parser.add_argument("--n", type=int, required=True, help="how many participants")
    parser.add_argument("--prefix", default="P", help="id prefix (default P: P01, P02, ...)")
    parser.add_argument("--out", type=Path, required=True,
                        help="CSV to write (participant,token,server,command); keep it private")
    parser.add_argument("--server", default="http://127.0.0.1:8000",
                        help="the server's address as participants reach it (default "
                             "http://127.0.0.1:8000)")
    parser.add_argument("--files", type=Path, default=None, metavar="DIR",
                        help="also write one <participant>.cgvq-invite.json per participant")


def run(args: argparse.Namespace) -> int:
    from study_server.operations import invite

    invites = invite(args.study, args.n, args.out, prefix=args.prefix, server=args.server,
                     files_dir=args.files)
    print(f"invited {len(invites)} participant(s): {invites[0].participant} .. "
          f"{invites[-1].participant}; tokens in {args.out} (keep it private; the server "
          "stores only their hashes)")
    print(f"send each participant their line, e.g.: {invites[0].command()}")
    if args.files is not None:
        print(f"invite files: {args.files}/<participant>.cgvq-invite.json "
              "(cgvq-study run --invite FILE)")
    return 0
