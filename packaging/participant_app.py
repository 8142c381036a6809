"""Entry point of the frozen participant app (PyInstaller): the ``cgvq-study`` command line.

Opened with an invitation file (dragged onto the app, "Open with", a double-click where the
file type is associated), it runs that invitation; opened with nothing (a double-click on
the app), it says how to take part. Both wait for Enter before they end: the console window
the system opened for the app closes with it, and with it the last lines (an error, "send
this file back", uploads still to come).
"""

import contextlib
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


def wait_for_enter() -> None:
    """Keep the console window open until the participant has read it (not when nobody can
    press Enter: no console, or input from a file)."""
    if sys.stdin is not None and sys.stdin.isatty():
        with contextlib.suppress(EOFError, KeyboardInterrupt):
            input("Press Enter to close this window.")


def run(args: list[str]) -> int:
    argv = command_line(args)
    if argv is None:
        print(HOW_TO)
        wait_for_enter()
        return 0
    if argv == args:  # typed in a terminal, which stays open
        return main(argv)
    code = main(argv)
    sys.stdout.flush()
    wait_for_enter()
    return code


if __name__ == "__main__":
    multiprocessing.freeze_support()
    sys.exit(run(sys.argv[1:]))
