"""``cgvq-study backup STUDY``: an online copy of the server database."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "backup"
HELP = "copy the study server's database safely, also while it serves"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, help="study folder")
    parser.add_argument("--out", type=Path, default=None,
                        help="backup file (default STUDY/server/backups/state-<UTC time>.sqlite)")


def run(args: argparse.Namespace) -> int:
    from study_server.operations import backup

    path = backup(args.study, args.out)
    print(f"backup written: {path} (integrity checked; it holds personal data: keep it "
          "as safe as the server)")
    return 0
