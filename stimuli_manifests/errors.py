"""The toolkit's error base and the one exception type of ``stimuli_manifests``.

Every error a user can cause anywhere in the toolkit derives from :class:`ToolkitError`; each
package has its own subclass (``StimuliError`` here, ``StudyError``, ``AnalysisError``,
``CGVQMError``) whose message names the file or field and says what to do. The three CLIs
share one runner (:mod:`stimuli_manifests.cli_runner`) that prints it as one line and exits 2.
"""

from __future__ import annotations


class ToolkitError(Exception):
    """A problem the user can fix; the message says what was wrong and what to do."""


class MissingExtraError(ToolkitError):
    """A command needs an optional part of the toolkit (an install extra) that is absent."""


class StimuliError(ToolkitError):
    """A problem with a manifest or a stimulus file that the user can fix."""


class ManifestError(StimuliError):
    """The manifest is malformed, inconsistent or refers to files it may not."""


class VideoError(StimuliError):
    """A video (or frame folder / .npy array) is missing, corrupt, empty or unsupported."""


class UnshowableVideoError(VideoError):
    """A video that decodes but that the toolkit would show and score otherwise than media
    players do (a display matrix, non-square pixels): re-encoding fixes it."""


class TableError(StimuliError):
    """A CSV table (ratings, scores, DMOS) lacks columns or has an unsupported format version."""


class LockedError(StimuliError):
    """Another process holds a file's lock (:mod:`stimuli_manifests.file_lock`); the message
    names it and says what to do. Packages raise their own type through a subclass."""
