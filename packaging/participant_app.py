"""Entry point of the frozen participant app (PyInstaller): the ``cgvq-study`` command line.

Opened with an invitation file (dragged onto the app, "Open with", a double-click where the
file type is associated), it runs that invitation; opened with nothing (a double-click on
the app), it says how to take part and waits, so a console window does not flash and close.
"""

import multiprocessing
import sys

from cgvq_cli.study_cli import main

INVITE_SUFFIX = ".cgvq-invite.json"
HOW_TO = ("This is the study app. To take part, open your invitation file "
          f"(*{INVITE_SUFFIX}) with it: drag the file onto the app, or run\n"
          f"    cgvq-study run --invite YOUR{INVITE_SUFFIX}\n"
          "Experimenters: cgvq-study --help lists every command.")


def command_line(args: list[str]) -> list[str] | None:
    """The ``cgvq-study`` arguments for what the app was opened with (None: nothing)."""
    if len(args) == 1 and args[0].lower().endswith(INVITE_SUFFIX):
        return ["run", "--invite", args[0]]
    return args or None


def run(args: list[str]) -> int:
    argv = command_line(args)
    if argv is None:
        print(HOW_TO)
        if sys.stdin is not None and sys.stdin.isatty():
            input("Press Enter to close this window.")
        return 0
    return main(argv)


if __name__ == "__main__":
    multiprocessing.freeze_support()
    sys.exit(run(sys.argv[1:]))
