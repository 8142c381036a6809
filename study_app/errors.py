"""The one exception type of ``study_app``: problems a user or experimenter can fix."""

from __future__ import annotations


class StudyError(Exception):
    """A study folder, session file or display problem, with a message that says what to do."""
