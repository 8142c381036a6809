"""The one exception type of the study side (session store, study server, player):
problems a user or experimenter can fix."""

from __future__ import annotations

from stimuli_manifests.errors import ToolkitError


class StudyError(ToolkitError):
    """A study folder, session file or display problem, with a message that says what to do."""
