"""The one exception type of ``stimuli_manifests``.

Every error a user can cause (bad manifest, path escaping the root, checksum mismatch, corrupt
or unsupported video) is raised as :class:`StimuliError` or a subclass, with a message that
names the file or field and says what to do. CLIs turn it into one line and exit code 2.
"""

from __future__ import annotations


class StimuliError(Exception):
    """A problem with a manifest or a stimulus file that the user can fix."""


class ManifestError(StimuliError):
    """The manifest is malformed, inconsistent or refers to files it may not."""


class VideoError(StimuliError):
    """A video (or frame folder / .npy array) is missing, corrupt, empty or unsupported."""
