"""The one exception type of the analysis package."""

from __future__ import annotations

from stimuli_manifests.errors import ToolkitError


class AnalysisError(ToolkitError):
    """A problem the user can fix (bad path, unreadable input, nothing left to analyse).

    The message says what was wrong and what to do; the CLI prints it as one line.
    """
