"""Command line of ``cgvq-study``: parses arguments, prints, sets exit codes.

Each subcommand lives in its own module under ``cgvq_cli.study_commands``; this module only wires
them together. The toolkit's one CLI runner turns every user error (``ToolkitError``, a
missing install extra, a bad path) into one line on stderr and exit code 2. A command module
may set ``EXTRA`` to the install extra it needs (named in the message when it is missing).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from types import ModuleType

from stimuli_manifests.cli_runner import OneLineParser, run_command

from .study_commands import COMMANDS


def _command_modules() -> list[ModuleType]:
    modules = []
    for name in COMMANDS:
        try:
            modules.append(importlib.import_module(f"cgvq_cli.study_commands.{name}"))
        except ModuleNotFoundError as exc:
            if exc.name != f"cgvq_cli.study_commands.{name}":
                raise
    return modules


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, ModuleType]]:
    parser = OneLineParser(
        prog="cgvq-study",
        description="Run a video-quality rating study and prepare its stimuli.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    handlers: dict[str, ModuleType] = {}
    for module in _command_modules():
        module.register(sub.add_parser(module.NAME, help=module.HELP, description=module.HELP))
        handlers[module.NAME] = module
    return parser, handlers


def main(argv: list[str] | None = None) -> int:
    parser, handlers = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s: %(message)s"
    )
    if args.command is None:
        parser.print_help()
        return 0
    module = handlers[args.command]
    return run_command(f"cgvq-study {args.command}", lambda: module.run(args),
                       extra=getattr(module, "EXTRA", None))


if __name__ == "__main__":
    sys.exit(main())
