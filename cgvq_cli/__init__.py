"""The console scripts ``cgvq-study``, ``cgvq-analyze`` and ``cgvqm``.

Every script is installed by every install, the participant's base install included, but the
analysis and the metric need their extras. Each entry point here imports its CLI only when
called, so a missing extra ends in one line naming it (exit 2) rather than a traceback.
"""

from __future__ import annotations

import importlib
import sys

from stimuli_manifests.cli_runner import EXIT_USER_ERROR, one_line
from stimuli_manifests.extras import explain_missing


def _launch(module: str, prog: str, extra: str | None) -> int:
    try:
        cli = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        missing = explain_missing(exc, what=prog, extra=extra)
        if missing is None:
            raise
        print(f"{prog}: error: {one_line(missing)}", file=sys.stderr)
        return EXIT_USER_ERROR
    return int(cli.main())


def study() -> None:
    sys.exit(_launch("cgvq_cli.study_cli", "cgvq-study", None))


def analyze() -> None:
    sys.exit(_launch("analysis.cli", "cgvq-analyze", "analysis"))


def cgvqm() -> None:
    sys.exit(_launch("cgvqm_core.cli", "cgvqm", "metric"))
