"""Subcommands of ``cgvq-study``, one module each.

Every module here defines ``NAME``, ``HELP``, ``register(parser)`` (adds its arguments) and
``run(args) -> int`` (does the work, returns the exit code). ``cgvq_cli.study_cli`` discovers them
in the order of ``COMMANDS``; a module that is not present yet is simply not offered.
"""

COMMANDS = ("init", "panel", "preview", "run", "check", "export", "verify", "synth",
            "simulate", "serve", "invite", "pull", "backup", "withdraw", "allocation")
