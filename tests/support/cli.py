"""Running the toolkit's commands inside a test, with what they printed."""

from __future__ import annotations

from cgvq_cli.study_cli import main as study_main


def study_init(capsys, *args: object) -> tuple[int, str, str]:
    """``cgvq-study init ARGS``: (exit code, stdout, stderr)."""
    code = study_main(["init", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def analyze(capsys, *args: object) -> tuple[int, str, str]:
    """``cgvq-analyze ARGS``: (exit code, stdout, stderr)."""
    from analysis.cli import main as analyze_main

    code = analyze_main(list(map(str, args)))
    out, err = capsys.readouterr()
    return code, out, err
